"""``python -m spacecal.cli``: the same program as ``python -m spacecal``."""

from spacecal.__main__ import run

if __name__ == "__main__":
    run()
