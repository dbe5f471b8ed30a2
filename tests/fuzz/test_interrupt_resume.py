"""Ctrl-C at each step of ``spacecal acquire --resume``: one line on stderr, exit 1, no
traceback, every sample recorded before kept, and the progress file left for the next resume.

KeyboardInterrupt is raised from a function on the resume path (reading the progress and
the streams' last time, re-planning and gating, reopening the streams, the approach to the
interrupted move, the moves, and deriving the paired recording at the end).
"""

from __future__ import annotations

import contextlib
import io
import shutil

import pytest

from spacecal import app
from spacecal.cli import main
from spacecal.core.errors import SpacecalError

STEPS = [
    "spacecal.app.acquisition.last_time_s",
    "spacecal.workflows.acquisition.read_progress",
    "spacecal.io.raw_streams.drop_partial_last_row",
    "spacecal.workflows.acquisition.RawStreamWriter",
    "spacecal.workflows.acquisition._approach",
    "spacecal.workflows.acquisition._derive_recording",
]
STREAMS = ("rec.robot.csv", "rec.tracker.csv")


@pytest.fixture(scope="module")
def stopped(tmp_path_factory):
    """A simulated acquisition stopped by Ctrl-C at sample 150, with half a row left behind."""
    folder = tmp_path_factory.mktemp("stopped")

    def hook(samples, visible, move, label):
        if samples == 150:
            raise KeyboardInterrupt

    with pytest.raises(SpacecalError, match="interrupted"):
        app.acquire(app.AcquireSettings(str(folder / "rec.csv"), scenario="paper-white"), on_sample=hook)
    with open(folder / "rec.tracker.csv", "a") as stream:
        stream.write("12.5,0.1")  # a row the interruption cut
    return folder


def _interrupt(*args, **kwargs):
    raise KeyboardInterrupt


def _complete_rows(data: bytes) -> bytes:
    return data[: data.rfind(b"\n") + 1]


@pytest.mark.parametrize("step", STEPS, ids=[s.rsplit(".", 1)[1] for s in STEPS])
def test_ctrl_c_during_resume_is_one_line_and_keeps_the_data(stopped, tmp_path, monkeypatch, step):
    folder = tmp_path / "run"
    shutil.copytree(stopped, folder)
    before = {name: _complete_rows((folder / name).read_bytes()) for name in STREAMS}
    argv = ["acquire", "--scenario", "paper-white", "-o", str(folder / "rec.csv"), "--resume"]
    err = io.StringIO()
    with monkeypatch.context() as patch:
        module, name = step.rsplit(".", 1)
        patch.setattr(module + "." + name, _interrupt)
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = main(argv)
    lines = [line for line in err.getvalue().splitlines() if line.strip() and not line.startswith("[")]
    assert code == 1 and len(lines) == 1, err.getvalue()
    assert "interrupted" in lines[0] and "Traceback" not in err.getvalue() and "internal" not in lines[0]
    for name in STREAMS:
        assert (folder / name).read_bytes().startswith(before[name]), f"{name} lost rows"
    assert (folder / "rec.progress.json").is_file()  # what --resume starts from
