"""The hardware tests, repeated: flakiness and the time from each fault to a still robot.

Runs ``pytest tests/adapters`` (the UR, NDI and OpenIGTLink adapters against the protocol
fakes, through the real client libraries) ``--repeats`` times, each in a fresh process, and
prints two tables:

* every test that failed or errored in any repeat, with how often (an empty table means no
  flakiness over the repeats);
* for every way the robot stops (``tests/adapters/test_ur_stops.py``), the time from the fault
  to the fake controller's joints standing still and to the end of ``spacecal acquire``:
  median and largest over the repeats, with the cause line the user sees.

    python benchmarks/hardware_repeats.py [--repeats 10] [-- extra pytest arguments, e.g. -n 2]
"""

from __future__ import annotations

import argparse
import re
import statistics
import subprocess
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Printed by the stop tests: "<cause>: still 0.012 s after the fault; command ended after 2.41 s".
STOP_LINE = re.compile(
    r"^(?P<cause>[^:\n]+): still (?P<still>[0-9.]+) s after the fault; "
    r"command ended after (?P<ended>[0-9.]+) s",
    re.MULTILINE,
)
#: pytest's short summary with -ra: "FAILED tests/adapters/test_x.py::test_y - reason".
FAILURE_LINE = re.compile(r"^(FAILED|ERROR) (\S+)", re.MULTILINE)
#: pytest's last line: "== 61 passed, 1 failed in 512.3s ==".
TOTALS_LINE = re.compile(r"=+ (.*) in ([0-9.]+)s")


def one_run(extra: list[str]) -> tuple[str, float]:
    started = time.monotonic()
    # the stop tests print their times: shown with -s, or (test workers cannot pass -s output on)
    # in the report of passed tests, -rA (a later -ra, as in the project's addopts, would hide it)
    shown = ["-rA"] if any(a == "-n" or a.startswith("-n") for a in extra) else ["-s", "-ra"]
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "tests/adapters", *shown, "-p", "no:cacheprovider", *extra],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    return done.stdout + done.stderr, time.monotonic() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--log", type=Path, help="append every run's full output to this file")
    parser.add_argument("extra", nargs="*", help="further pytest arguments (after --)")
    args = parser.parse_args()
    failures: Counter[str] = Counter()
    stops: dict[str, list[tuple[float, float]]] = defaultdict(list)
    for k in range(args.repeats):
        output, seconds = one_run(args.extra)
        if args.log:
            with args.log.open("a") as log:
                log.write(f"\n===== run {k + 1} =====\n{output}")
        failed = [name for _, name in FAILURE_LINE.findall(output)]
        failures.update(failed)
        for match in STOP_LINE.finditer(output):
            # the line follows pytest's progress characters (and the file's name, first in a file)
            cause = re.sub(r"^(\S+\.py )?[.FEsx]*", "", match["cause"].strip())
            stops[cause].append((float(match["still"]), float(match["ended"])))
        totals = TOTALS_LINE.findall(output)
        summary = totals[-1][0] if totals else "no pytest summary"
        print(f"run {k + 1}/{args.repeats}: {summary} ({seconds:.0f} s)", flush=True)

    print()
    print(f"| test that failed | runs failed of {args.repeats} |")
    print("|---|---|")
    for name, count in failures.most_common():
        print(f"| {name} | {count} |")
    print()
    print(
        "| stop (the line's cause) | fault to still, median / max (s) | fault to end, median / max (s) "
        "| runs |"
    )
    print("|---|---|---|---|")
    for cause, times in sorted(stops.items()):
        still = [t[0] for t in times]
        ended = [t[1] for t in times]
        print(
            f"| {cause} | {statistics.median(still):.3f} / {max(still):.3f} | "
            f"{statistics.median(ended):.2f} / {max(ended):.2f} | {len(times)} |"
        )


if __name__ == "__main__":
    main()
