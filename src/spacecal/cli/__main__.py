"""``python -m spacecal.cli``."""

import sys

from spacecal.cli.main import main

sys.exit(main())
