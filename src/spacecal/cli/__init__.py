"""The ``spacecal`` command line: parse, call one app function, print (see :mod:`spacecal.cli.main`)."""

from spacecal.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
