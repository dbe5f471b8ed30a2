"""A stop asked for by a signal is never lost: when Python swallows the KeyboardInterrupt (it
landed in a weakref callback, as importlib's module-lock clean-up is), the acquisition still
stops at its next frame, and nothing is printed about the swallowed exception."""

import gc
import signal
import subprocess
import sys
import weakref
from pathlib import Path

import numpy as np
import pytest

from spacecal.core import interrupts


class _Referent:
    pass


def _lose_an_interrupt_in_a_weakref_callback() -> None:
    """Deliver SIGINT while Python runs a weakref callback: the handler's exception is
    'ignored' there, as in the importlib race."""

    def callback(_):
        signal.raise_signal(signal.SIGINT)

    referent = _Referent()
    reference = weakref.ref(referent, callback)
    del referent
    gc.collect()
    assert reference() is None


def test_a_lost_interrupt_is_kept_and_raised_by_the_loop(capsys):
    with interrupts.signals_as_interrupts():
        _lose_an_interrupt_in_a_weakref_callback()  # Python prints nothing, raises nothing here
        assert interrupts.stop_requested() == "Ctrl-C"
        with pytest.raises(interrupts.StopRequested, match="Ctrl-C"):
            interrupts.raise_if_stop_requested()
    assert interrupts.stop_requested() is None  # spent when the command ends
    assert "Exception ignored" not in capsys.readouterr().err


def test_a_simulated_acquisition_stops_on_a_lost_interrupt(tmp_path, capsys):
    """Through the whole acquisition: the interrupt is lost before the run reaches its loop,
    and the run still stops at the first frame, keeping what it recorded."""
    from spacecal import app
    from spacecal.workflows import acquisition

    original = acquisition.run_plan

    def run_plan_after_a_lost_interrupt(*args, **kwargs):
        _lose_an_interrupt_in_a_weakref_callback()
        return original(*args, **kwargs)

    acquisition.run_plan = run_plan_after_a_lost_interrupt
    try:
        with interrupts.signals_as_interrupts(), pytest.raises(acquisition.AcquisitionStopped) as stopped:
            app.acquire(app.AcquireSettings(str(tmp_path / "rec.csv"), scenario="paper-white"))
    finally:
        acquisition.run_plan = original
    assert "interrupted by the user (Ctrl-C)" in str(stopped.value)
    assert stopped.value.result.moves_completed == 0 and np.isfinite(stopped.value.result.samples_written)
    assert "Exception ignored" not in capsys.readouterr().err


def test_a_stop_while_the_program_starts_ends_it_with_one_line(tmp_path):
    """A stop that lands while the modules load (held, not raised) ends the command before it
    does anything, with the command line's one line and exit 1, never an import's traceback."""
    program = (
        "import os, signal, sys\n"
        "from spacecal.core import interrupts\n"
        "interrupts.hold_stops_while_starting()\n"
        "os.kill(os.getpid(), signal.SIGINT)  # as if Ctrl-C came during the imports below\n"
        "from spacecal.cli.main import console_main\n"
        "sys.argv = ['spacecal', 'acquire', '--scenario', 'paper-white', '-o', 'rec.csv']\n"
        "console_main()\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", program], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 1, done.stderr
    assert (
        done.stderr.strip()
        == "spacecal: error: interrupted by the user (Ctrl-C); every file written is complete"
    )
    assert list(tmp_path.iterdir()) == []  # nothing was started


def test_the_console_script_holds_stops_while_it_starts():
    import tomllib

    scripts = tomllib.loads((Path(__file__).parents[2] / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["spacecal"] == "spacecal.__main__:run"
    source = (Path(__file__).parents[2] / "src" / "spacecal" / "__main__.py").read_text()
    assert source.index("hold_stops_while_starting()") < source.index("from spacecal.cli")
