"""The report of scripts/stress_ci.sh: from the JUnit XML of each run, the suite's wall time, the
failures per test (with the first line of each failure) and the slowest tests.

    python scripts/stress_ci_report.py DIR [--slowest 15]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dir", type=Path, help="the directory of run-*.xml files")
    p.add_argument("--slowest", type=int, default=15, help="how many of the slowest tests to list")
    args = p.parse_args(argv)
    runs = sorted(args.dir.glob("run-*.xml"), key=lambda f: int(f.stem.split("-")[1]))
    if not runs:
        print(f"stress_ci_report: no run-*.xml in {args.dir}", file=sys.stderr)
        return 2
    failures: dict[str, list[str]] = defaultdict(list)
    durations: dict[str, list[float]] = defaultdict(list)
    suite_s, totals = [], []
    for run in runs:
        suite = ET.parse(run).getroot()
        suite = suite if suite.tag == "testsuite" else suite.find("testsuite")
        suite_s.append(float(suite.get("time", 0)))
        totals.append(int(suite.get("tests", 0)))
        for case in suite.iter("testcase"):
            name = f"{case.get('classname')}::{case.get('name')}"
            durations[name].append(float(case.get("time", 0)))
            for bad in list(case.findall("failure")) + list(case.findall("error")):
                first = (bad.get("message") or "").strip().splitlines()[:1]
                failures[name].append(f"{run.stem}: {first[0][:160] if first else bad.tag}")
    print(f"{len(runs)} runs under a one-core CPU burner, {max(totals)} tests each")
    print(
        f"suite time (pytest): mean {statistics.mean(suite_s):.0f} s, min {min(suite_s):.0f} s, "
        f"max {max(suite_s):.0f} s"
    )
    failed = sum(len(v) for v in failures.values())
    print(f"failures: {failed} in {len({f.split(':')[0] for v in failures.values() for f in v})} of {len(runs)} runs")
    for name, what in sorted(failures.items(), key=lambda kv: -len(kv[1])):
        print(f"  {len(what)}x {name}")
        for line in what:
            print(f"      {line}")
    print(f"slowest {args.slowest} tests (mean / max seconds over runs):")
    slow = sorted(durations.items(), key=lambda kv: -statistics.mean(kv[1]))[: args.slowest]
    for name, times in slow:
        print(f"  {statistics.mean(times):6.1f} / {max(times):6.1f}  {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
