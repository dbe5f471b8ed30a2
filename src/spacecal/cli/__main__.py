"""``python -m spacecal.cli``."""

import sys

from spacecal.cli.main import main

if __name__ == "__main__":
    sys.exit(main())
