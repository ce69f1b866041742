#!/usr/bin/python3
"""basis_specs.py NPGC NPG_RADIOSITY — one reader of `--basis` (npg_parse_basis, npg.h) behind npgc,
the Python module and the applications: the same specs given to `npgc train --basis`,
`npg.Trainer(basis=[...])` and `npg-radiosity train --basis` are refused with the same message (the
part after the spec, each interface naming its own option); a spec with an unknown key the same by
npgc and Python (the applications take no product=, so their list of keys is shorter); a good spec
accepted by npgc and Python. The module from PYTHONPATH (the build's python/)."""
import os, re, subprocess, sys, tempfile

import npg

npgc, radiosity = sys.argv[1], sys.argv[2]
PROG = "tests/programs/nested_division.npg"
BAD = ["v", "v:", ":cap=3", "v:cap=0", "v:cap=1000001", "v:cap=3x", "v:cap=", "v:energy=1.5", "v:energy=0",
       "v:energy=nan", "v:center=maybe", "v:cap=3,cap=4", "v:cap=3,,energy=0.5", "v:cap"]
UNKNOWN_KEY = ["v:size=3", "v:cap=2,colour=red"]
GOOD = ["x:cap=1", "x:cap=2,energy=0.9,center=off", "*:energy=0.99"]
failures = []


def cli_message(cmd, spec, prefix):
    r = subprocess.run(cmd, capture_output=True, text=True)
    line = r.stderr.strip().splitlines()[0] if r.stderr.strip() else ""
    m = re.match(re.escape(prefix) + r" --basis '" + re.escape(spec) + r"': (.*?)( \(npgc train --help.*)?$", line)
    if r.returncode != 2 or not m:
        failures.append("%s: exit %d, %r" % (" ".join(cmd[:2]), r.returncode, line))
        return None
    return m.group(1)


def py_message(full, spec):
    try:
        npg.Trainer(full, basis=[spec])
    except ValueError as e:
        m = re.match(r"Trainer: basis '" + re.escape(spec) + r"': (.*)$", str(e))
        return m.group(1) if m else "unexpected: " + str(e)
    return "accepted"


with tempfile.TemporaryDirectory(prefix="npg_basis_") as work:
    full = npg.compile(PROG).full()
    data, out = os.path.join(work, "DATA"), os.path.join(work, "OUT")
    for spec in BAD + UNKNOWN_KEY:
        a = cli_message([npgc, "train", PROG, data, "-o", out, "--basis", spec], spec, "npgc train:")
        b = py_message(full, spec)
        c = cli_message([radiosity, "train", "--out", out, "--basis", spec], spec, "npg-radiosity train:") \
            if spec in BAD else a
        if a is None or not (a == b == c):
            failures.append("%r: npgc %r, Python %r, npg-radiosity %r" % (spec, a, b, c))
    for spec in GOOD:
        r = subprocess.run([npgc, "train", PROG, data, "-o", out, "--basis", spec], capture_output=True, text=True)
        if "--basis" in r.stderr or py_message(full, spec) != "accepted":
            failures.append("%r: refused (%s)" % (spec, r.stderr.strip()))

for f in failures:
    print("FAIL:", f)
print("basis specs: %d refused alike by npgc, Python and npg-radiosity, %d with an unknown key by npgc and "
      "Python, %d accepted" % (len(BAD), len(UNKNOWN_KEY), len(GOOD)))
sys.exit(1 if failures else 0)
