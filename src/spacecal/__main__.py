"""``python -m spacecal`` and the ``spacecal`` console script.

Stops (Ctrl-C, SIGTERM, SIGHUP) are held while the command's modules load, so a stop that
comes early ends the command with its one line, never with a traceback from an import it cut
half-way (:func:`spacecal.core.interrupts.hold_stops_while_starting`).
"""

from spacecal.core import interrupts


def run() -> None:
    """The program: hold stops, load the command line, run it."""
    interrupts.hold_stops_while_starting()
    from spacecal.cli.main import console_main

    console_main()


if __name__ == "__main__":
    run()
