"""A motion the station runs (an acquisition or a check) in a process of its own.

The station serves pages, a live view and a record from one Python process. A motion there
would share its interpreter lock with the web server, and a robot library that crashes on
close (ur_rtde after a dropped control connection was seen to end in a segmentation fault)
would take the station with it. So each motion runs as the command line runs it: a process of
its own (``python -m spacecal.station.motion_process``), with the command line's signal
handling (:func:`spacecal.core.interrupts.signals_as_interrupts`), in which STOP is SIGINT,
i.e. Ctrl-C, and takes the command line's stop path: the robot is stopped, every sample is
kept, and the run says where it stopped.

The protocol on the child's pipes (trusted: the station starts this child itself):

- stdin: one pickled ``(motion, settings)``, ``motion`` being ``"acquire"`` (settings
  :class:`spacecal.app.AcquireSettings`), ``"check"`` (:class:`spacecal.app.CheckSettings`) or
  ``"verify"`` (:class:`spacecal.app.VerifySettings`, reached on the devices).
- stdout: pickled messages ``(kind, payload)``, flushed one by one: ``("started", None)``
  once SIGINT takes the command line's stop path, ``("plan", moves)``,
  ``("sample", (samples, visible, move_index, label))``, ``("frame", (time_s, segment,
  tracker_from_marker, base_from_tcp, recorded))`` (an acquisition's every tracker frame), and
  one last message: ``("done", CommandResult)``, ``("interrupted", reason)`` (the stop came
  before the app function could catch it) or ``("failed", one line)``. Anything the robot and
  tracker libraries print on the process's standard output goes to its standard error
  instead, so it never mixes with the messages.
"""

from __future__ import annotations

import faulthandler
import os
import pickle
import signal
import sys
import warnings
from typing import IO, Any

#: The kinds of message that end a child's report.
LAST_MESSAGES = ("done", "interrupted", "failed")
#: Why a motion stops when its station can no longer be told anything.
STATION_LOST = "the station that started the motion is gone"


def _channel() -> IO[bytes]:
    """The message channel: the process's original standard output. File descriptor 1 then
    points at standard error, so a C library's ``printf`` cannot corrupt the messages."""
    channel = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    return channel


#: How long a guidance in one session waits at the standoff for the insertion's confirmation
#: (a confirmation's lifetime), s; then it ends there without inserting.
PROCEED_WITHIN_S = 300.0


def wait_for_proceed(channel: IO[bytes], within_s: float = PROCEED_WITHIN_S) -> str:
    """The second confirmation the station sends down standard input (``("proceed", word)``).

    Raises
    ------
    InvalidInputError
        None came within ``within_s``, or the station closed the pipe without one.
    KeyboardInterrupt
        STOP (SIGINT) meanwhile.
    """
    import select

    from spacecal.core.errors import InvalidInputError

    ready, _, _ = select.select([channel], [], [], within_s)
    if not ready:
        raise InvalidInputError(
            f"the insertion was not confirmed within {within_s:.0f} s: the robot stays at the standoff"
        )
    try:
        kind, word = pickle.load(channel)
    except (EOFError, pickle.UnpicklingError, ValueError):
        raise InvalidInputError("the insertion was not confirmed: the robot stays at the standoff") from None
    if kind != "proceed":
        raise InvalidInputError("the insertion was not confirmed: the robot stays at the standoff")
    return str(word)


def one_session(motion: str, settings: Any) -> bool:
    """Whether a guidance's standoff is followed, in its own session, by the insertion the
    station confirms later: on simulated devices, where a new session would start a fresh
    simulated world with the robot at home rather than where the standoff left it."""
    return motion == "standoff" and bool(settings.devices.simulated)


def guide(motion: str, settings: Any, on_sample: Any, send: Any) -> Any:
    """A guidance stage (``standoff`` or ``insert``); on simulated devices (:func:`one_session`)
    the standoff's session then waits for the insertion's confirmation
    (:func:`wait_for_proceed`) and runs it."""
    import dataclasses

    from spacecal import app
    from spacecal.station.guide_step import stage_output

    if not one_session(motion, settings):
        return app.guide(settings, on_sample=on_sample)

    def then(standoff: Any) -> Any:
        send("stage", ("standoff", standoff.record))
        send("await", "insert")
        insertion = wait_for_proceed(sys.stdin.buffer)
        send("stage", ("insert", None))
        return dataclasses.replace(
            settings,
            stage="insert",
            insertion=insertion,
            confirm_insertion=True,
            output=stage_output(settings.output, "insert"),
        )

    return app.guide(settings, on_sample=on_sample, then=then)


def run_motion(motion: str, settings: Any, send: Any) -> None:
    """Run ``motion`` with ``settings`` and report through ``send(kind, payload)``.

    Raises nothing: every way out is one last message.
    """
    from spacecal import app
    from spacecal.core import interrupts
    from spacecal.core.text import exception_line

    def on_sample(samples: int, visible: int, move_index: int, label: str) -> None:
        send("sample", (samples, visible, move_index, label))

    # only an acquisition streams its frames to the page: drawing them shares the page's one
    # thread with STOP's click, and during a short insertion a loaded machine's draw delayed the
    # click past the insertion's end (the other motions' pages draw their set-up, not samples)
    def observer(time_s, segment, tracker_from_marker, base_from_tcp, recorded) -> None:
        send("frame", (time_s, segment, tracker_from_marker, base_from_tcp, recorded))

    out: app.CommandResult[Any]
    try:
        with interrupts.signals_as_interrupts(), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # as the command line: the last line says what happened
            send("started", None)
            if motion == "acquire":
                out = app.acquire(
                    settings, on_sample=on_sample, observer=observer, on_plan=lambda n: send("plan", n)
                )
            elif motion == "check":
                out = app.check(settings, on_sample=on_sample, on_plan=lambda n: send("plan", n))
            elif motion == "verify":
                from spacecal.app.verification import verify_on_devices

                out = verify_on_devices(settings, on_sample=on_sample, on_plan=lambda n: send("plan", n))
            elif motion in ("standoff", "insert"):
                out = guide(motion, settings, on_sample, send)
            else:
                raise ValueError(f"no motion {motion!r}")
        send("done", out)
    except KeyboardInterrupt as exc:
        send("interrupted", str(exc.args[0]) if exc.args else "Ctrl-C")
    except Exception as exc:  # every way out is shown on the station's page, in the CLI's words
        send("failed", exception_line(exc))


def main() -> None:
    """The child's entry point: read the motion, run it, end without the interpreter's
    teardown when a robot library left threads running (as the command line does)."""
    from spacecal.core import interrupts

    channel = _channel()
    # a motion that does not end after STOP is a fault to diagnose: SIGUSR1 prints where every
    # thread of it stands (on standard error, which the station passes through)
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    lost = False

    def send(kind: str, payload: Any) -> None:
        nonlocal lost
        if lost:
            return
        try:
            pickle.dump((kind, payload), channel, protocol=pickle.HIGHEST_PROTOCOL)
            channel.flush()
        except OSError:
            # the station is gone: nobody watches the robot, so it stops as on Ctrl-C
            lost = True
            if kind in LAST_MESSAGES:
                return
            interrupts.request_stop(STATION_LOST)
            raise interrupts.StopRequested(STATION_LOST) from None

    try:
        motion, settings = pickle.load(sys.stdin.buffer)
        run_motion(motion, settings, send)
    except KeyboardInterrupt:  # stopped before the motion began: nothing moved
        send("interrupted", "Ctrl-C")
    finally:
        try:
            channel.close()
        except OSError:
            pass
        sys.stderr.flush()
        from spacecal import app

        if app.end_programs_left_running():
            os._exit(0)


if __name__ == "__main__":
    main()
