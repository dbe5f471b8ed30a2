"""How long forcing a file to the disk takes on this machine, while other work runs.

A durable recording forces its rows to the disk (``fsync``) on a thread of its own
(:mod:`spacecal.io.background_sync`) because that wait can be long: beside loaded CI runs on a
2-core machine sharing a virtual disk it was measured at 6.4 s, 33.2 s and 34.6 s at worst. This
appends a 200-byte row every ``--period-ms``, flushes and syncs it
(:class:`spacecal.testing.disk_probe.DiskProbe`, which the stop tests run beside each run), and
prints how the waits were distributed, with every wait over ``--report-ms`` as it happens.
Run it at the priority the acquisition has (``nice -n -10`` where allowed) beside the work that
loads the machine.

    python benchmarks/fsync_latency.py [--seconds 600] [--period-ms 50] [--report-ms 100]
        [--folder PATH]
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np

from spacecal.testing.disk_probe import DiskProbe


def report(wait: float) -> None:
    print(f"{time.strftime('%H:%M:%S')} fsync waited {wait:.3f} s", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=600.0)
    parser.add_argument("--period-ms", type=float, default=50.0)
    parser.add_argument("--report-ms", type=float, default=100.0)
    parser.add_argument("--folder", help="where the probe's file goes (default: a temporary folder)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        period_s, stall_s = args.period_ms / 1000.0, args.report_ms / 1000.0
        probe = DiskProbe(args.folder or scratch, period_s=period_s, stall_s=stall_s, on_stall=report)
        time.sleep(args.seconds)
        probe.close()
    ms = np.array(probe.waits) * 1000.0
    print()
    print("| syncs | median (ms) | 99th percentile (ms) | 99.9th (ms) | longest (ms) |")
    print("|---|---|---|---|---|")
    print(
        f"| {len(ms)} | {np.median(ms):.1f} | {np.percentile(ms, 99):.1f} | "
        f"{np.percentile(ms, 99.9):.1f} | {ms.max():.1f} |"
    )


if __name__ == "__main__":
    main()
