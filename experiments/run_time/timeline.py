"""Where a Snakemake run's time goes: per rule, its jobs, their summed seconds and when the
first started and the last ended, from the run's log (.snakemake/log/*.snakemake.log).

  python experiments/run_time/timeline.py .snakemake/log/2026-12-06T015303.173533.snakemake.log

The log stamps each job's start and end to the second; a job's seconds run from the stamp
before its `rule` line to the stamp before its `Finished job` line.
"""

from __future__ import annotations

import argparse
import gzip
import collections
import datetime as dt
import re
import sys

STAMP = re.compile(r"^\[(\w{3} \w{3}\s+\d+ \d\d:\d\d:\d\d \d{4})\]$")
RULE = re.compile(r"^(?:local)?rule (\w+):")
JOB = re.compile(r"^\s+jobid: (\d+)")
FINISHED = re.compile(r"^Finished job(?:id:)? (\d+)")


def spans(lines) -> dict[str, list[tuple[float, float]]]:
    """rule -> [(start, end)] in seconds from the log's first stamp."""
    stamp = first = None
    started, rule_of, rule = {}, {}, None
    out = collections.defaultdict(list)
    for line in lines:
        m = STAMP.match(line.strip())
        if m:
            stamp = dt.datetime.strptime(re.sub(r"\s+", " ", m.group(1)), "%a %b %d %H:%M:%S %Y")
            first = first or stamp
            continue
        if (m := RULE.match(line)):
            rule = m.group(1)
        elif (m := JOB.match(line)) and rule:
            started[m.group(1)], rule_of[m.group(1)], rule = stamp, rule, None
        elif (m := FINISHED.match(line)) and m.group(1) in started:
            job = m.group(1)
            out[rule_of[job]].append(((started[job] - first).total_seconds(),
                                      (stamp - first).total_seconds()))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log")
    a = ap.parse_args(argv)
    opener = gzip.open if a.log.endswith(".gz") else open
    with opener(a.log, "rt") as f:
        table = spans(f.read().splitlines())
    print("| rule | jobs | job-seconds | first start (min) | last end (min) |")
    print("| --- | --- | --- | --- | --- |")
    for rule, s in sorted(table.items(), key=lambda kv: min(a for a, _ in kv[1])):
        print(f"| {rule} | {len(s)} | {sum(b - a for a, b in s):.0f} | "
              f"{min(a for a, _ in s) / 60:.1f} | {max(b for _, b in s) / 60:.1f} |")
    total = sum(b - a for s in table.values() for a, b in s)
    end = max(b for s in table.values() for _, b in s)
    print(f"\n{total:.0f} job-seconds; the last job ended {end / 60:.1f} min after the first began")
    return 0


if __name__ == "__main__":
    sys.exit(main())
