"""A stop asked for by a signal is never lost: when Python swallows the KeyboardInterrupt (it
landed in a weakref callback, as importlib's module-lock clean-up is), the acquisition still
stops at its next frame, and nothing is printed about the swallowed exception."""

import gc
import signal
import weakref

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
