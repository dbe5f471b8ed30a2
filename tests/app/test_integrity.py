"""What a calibration file vouches for, through the app functions: an edited calibration is
refused by every reader (check, export to every format and report unless --accept-edited;
verify, bound and acquire --prior outright), a future schema version by every reader in one
line, an older version is read with a note; a result file is not replaced without --force;
a calibration records the identities of what it belongs to; on real devices the check
compares them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from spacecal import app
from spacecal.app._common import other_devices, provenance_of
from spacecal.core.errors import InvalidInputError
from spacecal.geometry.transforms import axis_angle_transform
from spacecal.io.csv_core import metadata_path
from spacecal.io.digest import file_sha256
from spacecal.io.recording_csv import write_recording
from spacecal.io.results_json import read_calibration
from spacecal.records import CalibrationResult, Provenance
from spacecal.records.calibration import CALIBRATION_READABLE_VERSIONS

EDITED = "has been edited since it was written (content hash differs); pass --accept-edited to use it anyway"


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory, white_simulation):
    """A recording whose metadata names a tool definition and serials, and its calibration."""
    folder = tmp_path_factory.mktemp("integrity")
    recording = write_recording(white_simulation.recording, folder / "rec.csv")
    rom = folder / "marker.rom"
    rom.write_bytes(bytes(range(256)) * 3)  # only hashed here, never parsed
    meta = json.loads(metadata_path(recording).read_text())
    meta["marker"]["tool_definition"] = str(rom)
    meta["robot"]["serial_number"] = "20195301234"
    meta["tracker"]["serial"] = "P9-01234"
    metadata_path(recording).write_text(json.dumps(meta))
    out = app.calibrate(app.CalibrateSettings(str(recording), str(folder / "cal.json"), "paper"))
    return folder, recording, out.files_written[0]


def edited_copy(path: Path, edit, name="edited.json") -> Path:
    data = json.loads(path.read_text())
    edit(data)
    out = path.with_name(name)
    out.write_text(json.dumps(data, indent=2))
    return out


def shift_2_mm(data):
    data["tracker_from_base"][1][3] += 2.0


def turn_half_a_degree(data):
    turn = axis_angle_transform([0.0, 0.0, 1.0], np.radians(0.5))
    data["tracker_from_base"] = (turn @ np.array(data["tracker_from_base"])).tolist()


#: Edits of every top-level field (and a few nested ones) that leave a valid calibration.
EDITS = {
    "tracker_from_base by 2 mm": shift_2_mm,
    "tracker_from_base by 0.5 deg": turn_half_a_degree,
    "tcp_from_marker": lambda d: d["tcp_from_marker"][0].__setitem__(3, d["tcp_from_marker"][0][3] + 0.1),
    "schema_version": lambda d: d.update(schema_version=2),
    "spacecal_version": lambda d: d.update(spacecal_version="9.9"),
    "created_utc": lambda d: d.update(created_utc="2020-01-01T00:00:00+00:00"),
    "units": lambda d: d["units"].update(time="s"),
    "method": lambda d: d.update(method="ml"),
    "sample_counts": lambda d: d["sample_counts"].update(used=1),
    "diagnostics": lambda d: d["diagnostics"].update(note="fine"),
    "diagnostics.expected_error": lambda d: d["diagnostics"]["expected_error"].update(position_mm=0.01),
    "provenance": lambda d: d["provenance"].update(simulated=False),
    "provenance.devices.robot": lambda d: d["provenance"]["devices"]["robot"].update(url="ur://10.0.0.9"),
    "provenance.recording_sha256": lambda d: d["provenance"].update(recording_sha256="0" * 64),
    "covariance": lambda d: d.update(covariance={"note": "added"}),
    "predicted_tre_mm": lambda d: d.update(predicted_tre_mm={"site": 0.01}),
    "robot_model": lambda d: d.update(
        robot_model={
            "name": "UR10",
            "a_mm": [0, -612.7, -571.6, 0, 0, 0],
            "d_mm": [127.3, 0, 0, 163.9, 115.7, 92.2],
            "alpha_rad": [1.5708, 0, 0, 1.5708, -1.5708, 0],
        }
    ),
    "integrity": lambda d: d["integrity"].update(content_sha256="f" * 64),
    "a new key": lambda d: d.update(approved_by="me"),
}


def test_every_top_level_key_is_edited_by_some_case(calibrated):
    _, _, cal = calibrated
    keys = set(json.loads(cal.read_text()))
    covered = {name.split(" ")[0].split(".")[0] for name in EDITS}
    assert keys - {"schema"} <= covered  # 'schema' names another kind of file: refused outright


def _readers(tmp_path: Path, recording: Path):
    """Each reader that takes --accept-edited: (name, call(calibration, accept_edited))."""
    out = tmp_path
    return {
        "check": lambda cal, accept: app.check(
            app.CheckSettings(str(cal), recording=str(recording), accept_edited=accept)
        ),
        "report": lambda cal, accept: app.report(
            app.ReportSettings(str(cal), str(out / "r.html"), accept_edited=accept)
        ),
        "export --slicer": lambda cal, accept: app.export(
            app.ExportSettings(str(cal), slicer=str(out / "t.tfm"), accept_edited=accept)
        ),
        "export --plus": lambda cal, accept: app.export(
            app.ExportSettings(str(cal), plus=str(out / "p.xml"), accept_edited=accept)
        ),
        "export --igtl": lambda cal, accept: app.export(
            app.ExportSettings(str(cal), igtl="127.0.0.1:9", accept_edited=accept)
        ),
        "export --easy-handeye2": lambda cal, accept: app.export_ros(
            app.RosExportSettings(str(cal), easy_handeye2=str(out / "e.calib"), accept_edited=accept)
        ),
        "export --ros2-launch": lambda cal, accept: app.export_ros(
            app.RosExportSettings(str(cal), ros2_launch=str(out / "l.launch.py"), accept_edited=accept)
        ),
        "export --urdf": lambda cal, accept: app.export_ros(
            app.RosExportSettings(str(cal), urdf=str(out / "j.urdf"), accept_edited=accept)
        ),
        "export --static-tf": lambda cal, accept: app.export_ros(
            app.RosExportSettings(str(cal), static_tf=True, accept_edited=accept)
        ),
        "export --ur-calibration": lambda cal, accept: app.export_ros(
            app.RosExportSettings(str(cal), ur_calibration=str(out / "k.yaml"), accept_edited=accept)
        ),
    }


READERS = list(_readers(Path("."), Path(".")))


def _strict_readers(tmp_path: Path, recording: Path):
    """Readers that never use an edited calibration."""
    return {
        "verify": lambda cal: app.verify(app.VerifySettings(str(cal), points=3)),
        "bound": lambda cal: app.bound(app.BoundSettings(str(recording), str(cal), 0.1)),
        "acquire --prior": lambda cal: app.acquire(
            app.AcquireSettings(str(tmp_path / "acq.csv"), prior=str(cal), dry_run=True)
        ),
    }


STRICT = list(_strict_readers(Path("."), Path(".")))


@pytest.mark.parametrize("reader", READERS)
@pytest.mark.parametrize("edit", list(EDITS), ids=list(EDITS))
def test_an_edited_calibration_is_refused_by_every_reader(calibrated, tmp_path, reader, edit):
    _, recording, cal = calibrated
    edited = edited_copy(cal, EDITS[edit], name=f"edited_{tmp_path.name}.json")
    with pytest.raises(InvalidInputError) as error:
        _readers(tmp_path, recording)[reader](edited, False)
    assert str(error.value) == f"{edited} {EDITED}"
    assert not (tmp_path / "r.html").exists() and not list(tmp_path.glob("[tpejlk].*"))


@pytest.mark.parametrize("reader", STRICT)
@pytest.mark.parametrize("edit", ["tracker_from_base by 2 mm", "tracker_from_base by 0.5 deg", "diagnostics"])
def test_verify_bound_and_acquire_prior_never_use_an_edited_calibration(calibrated, tmp_path, reader, edit):
    _, recording, cal = calibrated
    edited = edited_copy(cal, EDITS[edit], name=f"edited_{tmp_path.name}.json")
    with pytest.raises(InvalidInputError) as error:
        _strict_readers(tmp_path, recording)[reader](edited)
    message = str(error.value)
    assert message.startswith(f"{edited} has been edited since it was written (content hash differs); ")
    assert f"{reader} does not use an edited calibration" in message and "\n" not in message


@pytest.mark.parametrize("reader", [r for r in READERS if r not in ("export --igtl",)])
def test_accept_edited_lets_it_through_with_a_note(calibrated, tmp_path, reader):
    _, recording, cal = calibrated
    # the report checks that the calibration belongs to its recording: a 2 mm shift does not
    edit = EDITS["diagnostics"] if reader == "report" else shift_2_mm
    edited = edited_copy(cal, edit, name=f"edited_{tmp_path.name}.json")
    note = (
        f"{edited} has been edited since it was written (content hash differs); used as --accept-edited asks"
    )
    call = _readers(tmp_path, recording)[reader]
    if reader == "export --ur-calibration":  # through the hash check, to the next refusal
        with pytest.raises(InvalidInputError, match="holds no identified robot model"):
            call(edited, True)
        return
    out = call(edited, True)
    assert note in out.notes and f"note: {note}" in out.lines


def test_an_unedited_calibration_passes_without_a_note(calibrated, tmp_path):
    _, recording, cal = calibrated
    out = app.check(app.CheckSettings(str(cal), recording=str(recording)))
    assert out.notes == ()
    assert (
        app.export(app.ExportSettings(str(cal), slicer=str(tmp_path / "t.tfm"))).lines[0].startswith("wrote")
    )


def version_2_of(path: Path, name="v2.json") -> Path:
    def downgrade(data):
        data.pop("integrity")
        data["schema_version"] = 2
        for key in ("recording_sha256", "tracker_stream_sha256", "tool_definition", "tool_definition_sha256"):
            data["provenance"].pop(key)

    return edited_copy(path, downgrade, name)


def test_an_older_calibration_is_read_with_a_note_that_it_cannot_be_verified(calibrated, tmp_path):
    _, recording, cal = calibrated
    old = version_2_of(cal, f"v2_{tmp_path.name}.json")
    note = (
        f"{old} is a version 2 calibration, written before calibrations carried a content hash: it cannot "
        "be verified (calibrating again writes one)"
    )
    assert note in app.check(app.CheckSettings(str(old), recording=str(recording))).notes
    assert f"note: {note}" in app.export(app.ExportSettings(str(old), slicer=str(tmp_path / "t.tfm"))).lines
    assert note in app.bound(app.BoundSettings(str(recording), str(old), 0.1)).notes


@pytest.mark.parametrize("reader", READERS + STRICT)
def test_a_future_schema_version_is_refused_by_every_reader_in_one_line(calibrated, tmp_path, reader):
    _, recording, cal = calibrated
    newest = max(CALIBRATION_READABLE_VERSIONS)
    future = edited_copy(
        cal, lambda d: d.update(schema_version=newest + 1), name=f"future_{tmp_path.name}.json"
    )
    calls = {
        **{k: (lambda c, f=f: f(c, True)) for k, f in _readers(tmp_path, recording).items()},
        **_strict_readers(tmp_path, recording),
    }
    with pytest.raises(InvalidInputError) as error:
        calls[reader](future)
    assert str(error.value) == (
        f"{future}: schema_version {newest + 1} is newer than this spacecal reads "
        f"({', '.join(map(str, CALIBRATION_READABLE_VERSIONS))}): written by a newer spacecal, update it "
        "to read this file"
    )


def test_the_calibration_records_what_it_belongs_to(calibrated):
    folder, recording, cal = calibrated
    provenance = read_calibration(cal).provenance
    assert provenance.recording_sha256 == file_sha256(recording)
    assert provenance.tool_definition == str((folder / "marker.rom").resolve())
    assert provenance.tool_definition_sha256 == file_sha256(folder / "marker.rom")
    assert provenance.devices["robot"]["serial"] == "20195301234"
    assert provenance.devices["robot"]["model"] == "UR10"
    assert provenance.devices["tracker"]["serial"] == "P9-01234"
    assert provenance.tracker_stream is None and provenance.tracker_stream_sha256 is None


def test_two_raw_streams_are_both_hashed(white_simulation, tmp_path):
    from spacecal.io.recordings import open_path, write_raw_recording
    from spacecal.records import RawRecording

    robot, tracker = write_raw_recording(RawRecording.from_paired(white_simulation.recording), tmp_path / "s")
    opened = open_path(robot, tracker, 0.0)
    provenance = provenance_of(opened.recording, opened.source, robot)
    assert provenance.recording_sha256 == file_sha256(robot) != provenance.tracker_stream_sha256
    assert provenance.tracker_stream_sha256 == file_sha256(tracker)
    assert provenance.source is not None and provenance.source.time_offset_s == 0.0
    assert provenance.source.pairing is not None and provenance.source.pairing.offset_origin == "given"


def test_a_missing_tool_definition_is_recorded_by_path_with_a_note(calibrated, tmp_path, white_simulation):
    recording = write_recording(white_simulation.recording, tmp_path / "rec.csv")
    meta = json.loads(metadata_path(recording).read_text())
    meta["marker"]["tool_definition"] = "gone.rom"
    metadata_path(recording).write_text(json.dumps(meta))
    out = app.calibrate(app.CalibrateSettings(str(recording), str(tmp_path / "cal.json"), "paper"))
    gone = str((tmp_path / "gone.rom").resolve())
    assert out.record.provenance.tool_definition == gone
    assert out.record.provenance.tool_definition_sha256 is None
    assert any(gone in note and "not there" in note for note in out.notes)


# -- replacing files -------------------------------------------------------------------------


def test_calibrate_does_not_replace_a_calibration_without_force(calibrated, tmp_path):
    folder, recording, cal = calibrated
    target = tmp_path / "cal.json"
    target.write_bytes(cal.read_bytes())
    with pytest.raises(InvalidInputError) as error:
        app.calibrate(app.CalibrateSettings(str(recording), str(target), "paper"))
    assert (
        str(error.value)
        == f"{target}: an existing calibration; choose another file or pass --force to replace it"
    )
    assert target.read_bytes() == cal.read_bytes()
    (tmp_path / "notes.txt").write_text("mine\n")
    with pytest.raises(InvalidInputError, match=r"notes.txt: an existing file; .* pass --force"):
        app.calibrate(app.CalibrateSettings(str(recording), str(tmp_path / "notes.txt"), "paper"))
    out = app.calibrate(app.CalibrateSettings(str(recording), str(target), "paper", force=True))
    assert read_calibration(out.files_written[0]).integrity.verified


def _writers(tmp_path: Path, output: Path):
    """Each command writing a result file, with ``output`` as its output (inputs need not exist:
    the refusal comes first)."""
    o = str(output)
    return {
        "verify": lambda: app.verify(app.VerifySettings(str(tmp_path / "none.json"), output=o)),
        "verify --figure": lambda: app.verify(app.VerifySettings(str(tmp_path / "none.json"), figure=o)),
        "phantom": lambda: app.phantom(app.PhantomCommandSettings(output=o)),
        "phantom --figure": lambda: app.phantom(app.PhantomCommandSettings(figure=o)),
        "plan": lambda: app.plan(app.PlanSettings(output=o)),
        "pivot": lambda: app.pivot(app.PivotSettings(str(tmp_path / "poses"), output=o)),
        "register-landmarks": lambda: app.register_landmarks(
            app.RegisterLandmarksSettings(str(tmp_path / "s.mha"), str(tmp_path / "c.xml"), output=o)
        ),
        "demo --out": lambda: app.demo(app.DemoSettings(out=str(output.parent))),
    }


WRITERS = list(_writers(Path("."), Path(".")))
#: Existing files a result must not replace: each command's own kind, another kind, any file.
EXISTING = {
    "a calibration": ("calibration.json", {"schema": "spacecal.calibration", "schema_version": 3}),
    "a verification result": ("verification.json", {"schema": "spacecal.verification", "schema_version": 2}),
    "a plan": ("plan.json", {"schema": "spacecal.plan", "schema_version": 2}),
    "a pivot result": ("pivot.json", {"schema": "spacecal.pivot", "schema_version": 2}),
    "a phantom result": ("phantom.json", {"schema": "spacecal.phantom", "schema_version": 1}),
    "a landmark registration": (
        "reg.json",
        {"schema": "spacecal.landmark_registration", "schema_version": 1},
    ),
    "a file": ("notes.txt", "my notes\n"),
}


@pytest.mark.parametrize("writer", WRITERS)
@pytest.mark.parametrize("existing", list(EXISTING))
def test_no_result_file_is_replaced_without_force(tmp_path, writer, existing):
    name, content = EXISTING[existing]
    if writer == "demo --out":
        name = "calibration.json" if existing != "a file" else "verification_errors.png"
    target = tmp_path / name
    target.write_text(content if isinstance(content, str) else json.dumps(content, indent=2))
    before = target.read_bytes()
    with pytest.raises(InvalidInputError) as error:
        _writers(tmp_path, target)[writer]()
    kind = existing.removeprefix("a ").removeprefix("an ")
    assert (
        str(error.value) == f"{target}: an existing {kind}; choose another file or pass --force to replace it"
    )
    assert target.read_bytes() == before


@pytest.mark.parametrize(
    "call",
    [
        lambda cal, t: app.report(app.ReportSettings(str(cal), str(t))),
        lambda cal, t: app.export(app.ExportSettings(str(cal), slicer=str(t))),
        lambda cal, t: app.export_ros(app.RosExportSettings(str(cal), urdf=str(t))),
    ],
    ids=["report", "export --slicer", "export --urdf"],
)
def test_reports_and_exports_do_not_replace_a_result_file_either(calibrated, tmp_path, call):
    _, _, cal = calibrated
    other = tmp_path / "other.json"
    other.write_bytes(cal.read_bytes())
    with pytest.raises(
        InvalidInputError, match="an existing calibration; choose another file or pass --force"
    ):
        call(cal, other)
    history = tmp_path / "other.checks.jsonl"
    history.write_text(json.dumps({"schema": "spacecal.check", "schema_version": 2}) + "\n")
    with pytest.raises(
        InvalidInputError, match="an existing check history; choose another file or pass --force"
    ):
        call(cal, history)


# -- devices ---------------------------------------------------------------------------------


def on_devices(robot="ur://10.0.0.2", tracker="ndi://10.0.0.3", model="UR10", simulated=False):
    calibration = CalibrationResult(
        method="paper",
        tracker_from_base=np.eye(4),
        tcp_from_marker=np.eye(4),
        sample_counts={},
        diagnostics={},
        provenance=Provenance(
            simulated=simulated,
            devices={"robot": {"model": model, "url": robot}, "tracker": {"url": tracker}},
        ),
    )
    return calibration


@pytest.mark.parametrize(
    "robot,tracker,model",
    [
        ("ur://10.0.0.2", "ndi://10.0.0.3", "UR10"),
        ("UR://10.0.0.2/", "ndi://10.0.0.3:8765", "ur10"),  # the same devices, written otherwise
    ],
)
def test_the_same_devices_pass(robot, tracker, model):
    assert other_devices(on_devices(), robot, tracker, model, accept=False) == []


@pytest.mark.parametrize(
    "robot,tracker,model,named",
    [
        ("ur://10.0.0.9", "ndi://10.0.0.3", "UR10", "robot ur://10.0.0.2 recorded, ur://10.0.0.9 connected"),
        (
            "ur://10.0.0.2",
            "igtl://10.0.0.3",
            "UR10",
            "tracker ndi://10.0.0.3 recorded, igtl://10.0.0.3 connected",
        ),
        ("ur://10.0.0.2", "ndi://10.0.0.3", "UR5e", "a UR10 recorded, a UR5e connected"),
    ],
)
def test_other_devices_are_refused_unless_accepted(robot, tracker, model, named):
    with pytest.raises(InvalidInputError) as error:
        other_devices(on_devices(), robot, tracker, model, accept=False)
    message = str(error.value)
    assert named in message and "--accept-other-devices" in message and "\n" not in message
    notes = other_devices(on_devices(), robot, tracker, model, accept=True)
    assert len(notes) == 1 and named in notes[0]


def test_a_simulated_calibration_on_real_devices_is_refused():
    calibration = on_devices(simulated=True)
    with pytest.raises(InvalidInputError, match="calibrated on simulated devices"):
        other_devices(calibration, "ur://10.0.0.2", "ndi://10.0.0.3", "UR10", accept=False)


def test_a_calibration_without_device_urls_is_checked_with_a_note():
    calibration = on_devices().replace(provenance=Provenance(devices={"robot": {"model": "UR10"}}))
    notes = other_devices(calibration, "ur://10.0.0.2", "ndi://10.0.0.3", "UR10", accept=False)
    assert notes == ["the calibration records no device URLs: the devices connected were not compared"]


def with_serials(robot_serial="20195500000", tracker_serial="P6-00042"):
    calibration = on_devices()
    devices = calibration.provenance.devices
    return calibration.replace(
        provenance=Provenance(
            simulated=False,
            devices={
                "robot": {**devices["robot"], "serial": robot_serial},
                "tracker": {**devices["tracker"], "serial": tracker_serial},
            },
        )
    )


def test_the_same_serial_numbers_at_new_addresses_are_the_same_devices():
    notes = other_devices(
        with_serials(),
        "ur://10.0.0.7",
        "ndi://10.0.0.8",
        "UR10",
        accept=False,
        robot_identity={"serial": "20195500000"},
        tracker_identity={"serial": "P6-00042"},
    )
    assert notes == []


@pytest.mark.parametrize(
    "robot_identity,tracker_identity,named",
    [
        (
            {"serial": "20195500999"},
            {"serial": "P6-00042"},
            "robot serial number 20195500000 recorded, 20195500999 connected",
        ),
        (
            {"serial": "20195500000"},
            {"serial": "P6-00043"},
            "tracker serial number P6-00042 recorded, P6-00043 connected",
        ),
    ],
)
def test_another_device_at_the_same_address_is_refused_by_its_serial_number(
    robot_identity, tracker_identity, named
):
    with pytest.raises(InvalidInputError) as error:
        other_devices(
            with_serials(),
            "ur://10.0.0.2",
            "ndi://10.0.0.3",
            "UR10",
            accept=False,
            robot_identity=robot_identity,
            tracker_identity=tracker_identity,
        )
    assert named in str(error.value) and "--accept-other-devices" in str(error.value)


def test_a_device_that_does_not_say_its_serial_is_compared_by_address():
    with pytest.raises(InvalidInputError, match="robot ur://10.0.0.2 recorded, ur://10.0.0.9 connected"):
        other_devices(
            with_serials(), "ur://10.0.0.9", "ndi://10.0.0.3", "UR10", accept=False, robot_identity={}
        )
