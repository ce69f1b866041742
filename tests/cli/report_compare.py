#!/usr/bin/python3
"""report_compare.py A B: two report.json files (or two folders of them, compared file by
file) hold the same figures except timings: every key naming a time (seconds, t_s, t_pa,
speedup, ...) or derived from one is skipped; everything else must be equal, numbers too.
Used to show that a restructuring of an application leaves what it writes unchanged."""
import json
import os
import re
import sys

# a timing, or a figure computed from timings (speedups, per-second rates, thread counts chosen by the machine)
TIMING = re.compile(r"(seconds|^t_|_t$|speedup|time|fps|per_second|_ms$|^workers$|^train_threads$|^threads$|split)")


def walk(a, b, path, problems):
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if TIMING.search(k):
                continue
            if k not in a or k not in b:
                problems.append(f"{path}.{k}: only in {'B' if k not in a else 'A'}")
            else:
                walk(a[k], b[k], f"{path}.{k}", problems)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            problems.append(f"{path}: {len(a)} entries against {len(b)}")
        for i, (x, y) in enumerate(zip(a, b)):
            walk(x, y, f"{path}[{i}]", problems)
    elif a != b:
        problems.append(f"{path}: {a!r} against {b!r}")


def reports(root):
    if os.path.isfile(root):
        return {"": root}
    out = {}
    for d, _, files in os.walk(root):
        for f in files:
            if f.endswith(".json"):
                p = os.path.join(d, f)
                out[os.path.relpath(p, root)] = p
    return out


def main():
    if len(sys.argv) != 3:
        sys.exit("usage: report_compare.py A B (two report.json files or two folders)")
    ra, rb = reports(sys.argv[1]), reports(sys.argv[2])
    problems = [f"{k}: only in {'A' if k in ra else 'B'}" for k in sorted(set(ra) ^ set(rb))]
    for k in sorted(set(ra) & set(rb)):
        try:
            a, b = (json.load(open(p[k])) for p in (ra, rb))
        except (OSError, ValueError) as e:
            problems.append(f"{k}: {e}")
            continue
        walk(a, b, k or "report", problems)
    for p in problems[:40]:
        print(p)
    if problems:
        sys.exit(f"report_compare: {len(problems)} difference(s) between {sys.argv[1]} and {sys.argv[2]}")
    print(f"report_compare: {len(ra)} report(s) equal apart from timings")


if __name__ == "__main__":
    main()
