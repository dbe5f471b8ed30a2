"""The loopback network of this test process's fake devices.

The UR fake needs fixed ports, so every fake world and peer gets its own loopback address in
``127.NETWORK.x.y``. Test workers of one run get different networks (the worker's number is
part of it, for up to 8 workers); test runs side by side on one machine differ by their
process ids, so they rarely share one.
"""

import os
import re

_WORKER = int(re.sub(r"\D", "", os.environ.get("PYTEST_XDIST_WORKER", "")) or 0)
#: Second octet of this process's addresses: 20..219.
NETWORK = 20 + 8 * (os.getpid() % 25) + _WORKER % 8
