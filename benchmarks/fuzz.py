"""Fuzz every command of the command line and print what happened, per command and per class.

Usage::

    python benchmarks/fuzz.py                      # the thorough profile (>= 2,000 cases)
    python benchmarks/fuzz.py --profile fast       # the CI profile
    python benchmarks/fuzz.py --command calibrate  # one command
    python benchmarks/fuzz.py --show               # print every case that did not pass

Each case copies the base inputs into a fresh folder, mutates one file or option (classes:
encoding, types, numbers, consistency, overwrite, arguments, valid) and runs
``spacecal.cli.main`` in this process with a time limit; see :mod:`spacecal.testing.fuzz`.
"""

from __future__ import annotations

import argparse
import random
import sys
import tempfile
import time
from pathlib import Path

from spacecal.testing.fuzz import (
    COMMANDS,
    RandomPick,
    build_base,
    build_case,
    main_summary,
    plan_cases,
    prepare,
    run_case,
)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default="thorough", choices=["fast", "thorough"])
    parser.add_argument("--command", action="append", help="only these commands")
    parser.add_argument("--klass", action="append", help="only these mutation classes")
    parser.add_argument("--seed", type=int, default=2024)
    parser.add_argument("--show", action="store_true", help="print every case that did not pass")
    parser.add_argument("--limit-s", type=float, default=20.0, help="CPU s per case (6x on the clock)")
    args = parser.parse_args()
    rng = random.Random(args.seed)
    results = []
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="spacecal-fuzz-") as scratch:
        base = build_base(Path(scratch) / "base")
        clean = Path(scratch) / "clean"
        prepare(base, clean)
        clean_case = build_case(RandomPick(rng), clean, "calibrate", "valid", fast=False)
        clean_case.compare = None
        prepare(base, clean)
        clean_case.argv = list(COMMANDS["calibrate"]["argv"])
        run_case(clean_case, clean)
        for command, klass, count in plan_cases(args.profile):
            if args.command and command not in args.command:
                continue
            if args.klass and klass not in args.klass:
                continue
            for _ in range(count):
                folder = Path(scratch) / "case"
                prepare(base, folder)
                case = build_case(RandomPick(rng), folder, command, klass, fast=args.profile == "fast")
                result = run_case(case, folder, args.limit_s, clean / "out.json")
                results.append(result)
                if args.show and result.outcome != "pass":
                    print(
                        f"[{result.outcome}] {command} / {klass}: {case.label} -> exit {result.code}\n"
                        f"    argv: {case.argv}\n    {result.detail.strip()[-1500:]}\n",
                        flush=True,
                    )
    print(main_summary(results))
    print(
        f"\n{len(results)} cases in {time.monotonic() - started:.0f} s "
        f"(profile {args.profile}, seed {args.seed})"
    )
    return 0 if all(r.outcome == "pass" for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
