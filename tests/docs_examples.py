#!/usr/bin/python3
"""docs_examples.py BUILD_DIR — every program in docs/*.md is checked.

Each fenced ```npg block of docs/*.md is written to a file and must pass
`npgc check`. Comment lines inside a block state results, and are checked:

  # expect-class: {a, b}        a basis class with exactly these members
  # expect-stages: y.t1, y      the stages, in evaluation order
  # expect-kind: y inverse      the kind of a stage
  # example: x = [1, 2] gives y = [6, 0.25]
                                the full evaluator (npgc eval --full) on
                                these values (params and inputs, `;`
                                between names) gives these outputs (1e-12)

A ```npg-error block must fail `npgc check`, and its `# expect-error: TEXT`
line must be part of the first line npgc writes to stderr.

A ```console block is a session: each `$ COMMAND` line is run (`build/` is the
build directory, `/tmp/NAME` a fresh temporary folder), and every other line
is output it must print, in order (numbers compared to 1 %, and equal below
1e-12 as rounding); `[exit N]` is its exit status, 0 unless stated.

Every relative link of docs/*.md and README.md must name a file that exists
(and a heading of it, for a #fragment), and no file of the repository may
point at the design document outside it (after `git clone` there is none).

Each folder of code (ir/, include/, scripts/, cmake/, docs/, bench/, tests/,
backends/*/, compiler/*/, stdlib/*/, examples/*/) has a README that names every
file in it (`stem.c/.h` names both), the parts of tests/ listed in
tests/README.md; the index READMEs of backends/, compiler/, stdlib/ and
examples/ name every sub-folder.
"""
import glob, json, os, re, subprocess, sys, tempfile

import numpy as np

build = sys.argv[1]
npgc = os.path.join(build, "npgc")
docs = sorted(glob.glob("docs/*.md"))
fence = re.compile(r"^```(npg|npg-error|console)\s*$")
failures = []
counts = {"npg": 0, "npg-error": 0, "console": 0, "expectations": 0, "links": 0, "map": 0}


def blocks(path):
    """(kind, first line number, text) of every npg block of a markdown file."""
    out, cur = [], None
    with open(path, encoding="utf-8") as f:
        for n, line in enumerate(f, 1):
            if cur is None:
                m = fence.match(line)
                if m:
                    cur = (m.group(1), n + 1, [])
            elif line.startswith("```"):
                out.append((cur[0], cur[1], "".join(cur[2])))
                cur = None
            else:
                cur[2].append(line)
    if cur is not None:
        failures.append("%s:%d: unterminated ```%s block" % (path, cur[1] - 1, cur[0]))
    return out


def values(text):
    """'x = [1, 2]; eps = 0.5' -> {'x': array, 'eps': array}"""
    out = {}
    for part in text.split(";"):
        name, _, lit = part.partition("=")
        out[name.strip()] = np.array(json.loads(lit.strip()), dtype=float)
    return out


def check_example(where, prog, text, line, rep, work):
    given, _, expected = line.partition(" gives ")
    given, expected = values(given), values(expected)
    data, ins, out = (os.path.join(work, d) for d in ("DATA", "IN", "OUT"))
    for d in (data, ins):
        os.makedirs(d, exist_ok=True)
    inputs = {i["name"] for i in rep["inputs"]}
    params = dict(re.findall(r"^param\s+(\w+)\s*:\s*(int|real)", text, re.M))  # check --json lists no params
    for name, v in given.items():
        if name in inputs:
            np.save(os.path.join(ins, name + ".npy"), v[None, ...])
        elif name in params:
            is_int = params[name] == "int"
            np.save(os.path.join(data, name + ".npy"), v.astype(np.int64) if is_int else v)
        else:
            failures.append("%s: example names '%s', neither a param nor an input" % (where, name))
            return
    r = subprocess.run([npgc, "eval", prog, "--full", data, ins, "-o", out], capture_output=True, text=True)
    if r.returncode != 0:
        failures.append("%s: npgc eval --full failed: %s" % (where, r.stderr.strip()))
        return
    for name, want in expected.items():
        got = np.load(os.path.join(out, name + ".npy"))[0]
        if got.shape != want.shape or not np.allclose(got, want, rtol=1e-12, atol=1e-12):
            failures.append("%s: %s is %s, the text says %s" % (where, name, got.tolist(), want.tolist()))


def check_block(path, first, text, work):
    where = "%s:%d" % (path, first)
    prog = os.path.join(work, "example.npg")
    with open(prog, "w") as f:
        f.write(text)
    r = subprocess.run([npgc, "check", prog, "--json"], capture_output=True, text=True)
    if r.returncode != 0:
        failures.append("%s: npgc check failed:\n%s" % (where, r.stderr))
        return
    rep = json.loads(r.stdout)
    classes = [sorted(c["members"]) for c in rep["classes"]]
    stages = [s["name"] for s in rep["stages"]]
    kinds = {s["name"]: s["kind"] for s in rep["stages"]}
    for line in text.splitlines():
        line = line.strip()
        m = re.match(r"# expect-class: \{(.*)\}$", line)
        if m:
            counts["expectations"] += 1
            want = sorted(x.strip() for x in m.group(1).split(","))
            if want not in classes:
                failures.append("%s: no class {%s}; the classes are %s" % (where, m.group(1), classes))
        m = re.match(r"# expect-stages: (.*)$", line)
        if m:
            counts["expectations"] += 1
            want = [x.strip() for x in m.group(1).split(",")]
            if want != stages:
                failures.append("%s: stages %s, the text says %s" % (where, stages, want))
        m = re.match(r"# expect-kind: (\S+) (.*)$", line)
        if m:
            counts["expectations"] += 1
            if kinds.get(m.group(1)) != m.group(2):
                failures.append("%s: stage %s is %s, the text says %s" % (where, m.group(1), kinds.get(m.group(1)),
                                                                           m.group(2)))
        m = re.match(r"# example: (.*)$", line)
        if m:
            counts["expectations"] += 1
            check_example(where, prog, text, m.group(1), rep, work)


def check_error_block(path, first, text, work):
    where = "%s:%d" % (path, first)
    m = re.search(r"^# expect-error: (.*)$", text, re.M)
    if not m:
        failures.append("%s: an npg-error block without '# expect-error:'" % where)
        return
    counts["expectations"] += 1
    prog = os.path.join(work, "example.npg")
    with open(prog, "w") as f:
        f.write(text)
    r = subprocess.run([npgc, "check", prog], capture_output=True, text=True)
    first_line = r.stderr.splitlines()[0] if r.stderr else ""
    if r.returncode == 0:
        failures.append("%s: npgc check accepted a program the text says is refused" % where)
    elif m.group(1).strip() not in first_line:
        failures.append("%s: npgc says '%s', the text says '%s'" % (where, first_line, m.group(1).strip()))


NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*(?:[eE][-+]?\d+)?)")


def same_line(want, got):
    """Lines equal but for white space, numbers to 1 % (rounding below 1e-12 is 0)."""
    w, g = " ".join(want.split()), " ".join(got.split())
    if NUMBER.sub("#", w) != NUMBER.sub("#", g):  # the same text around the numbers
        return False
    for a, b in zip(NUMBER.findall(w), NUMBER.findall(g)):
        x, y = float(a), float(b)
        if abs(x) < 1e-12 and abs(y) < 1e-12:
            continue
        if abs(x - y) > 1e-2 * max(abs(x), abs(y)):
            return False
    return True


def check_console(path, first, text, work):
    where = "%s:%d" % (path, first)
    session = []  # [command, expected lines, exit status]
    for line in text.splitlines():
        if line.startswith("$ "):
            session.append([line[2:], [], 0])
        elif not session:
            failures.append("%s: output before the first '$ ' command" % where)
            return
        elif re.fullmatch(r"\[exit (\d+)\]", line.strip()):
            session[-1][2] = int(line.strip()[6:-1])
        elif line.strip():
            session[-1][1].append(line)
    for cmd, expected, status in session:
        # the text's /tmp/NAME first: the build folder may itself lie under /tmp (a clone there)
        run = re.sub(r"/tmp/(\w+)", lambda m: os.path.join(work, m.group(1)), cmd)
        run = re.sub(r"(?<![\w/])build/", build.rstrip("/") + "/", run)
        r = subprocess.run(run, shell=True, capture_output=True, text=True)
        out = (r.stdout + r.stderr).splitlines()
        counts["expectations"] += 1 + len(expected)
        if r.returncode != status:
            failures.append("%s: '%s' exited %d, the text says %d:\n%s" % (where, cmd, r.returncode, status,
                                                                       r.stdout + r.stderr))
            continue
        at = 0
        for want in expected:
            while at < len(out) and not same_line(want, out[at].replace(work + "/", "/tmp/")):
                at += 1
            if at == len(out):
                failures.append("%s: '%s' did not print '%s'; it printed:\n%s" % (where, cmd, want.strip(),
                                                                              r.stdout + r.stderr))
                break
            at += 1


def slug(heading):
    """GitHub's anchor of a heading."""
    h = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return h.replace(" ", "-")


def anchors(path):
    with open(path, encoding="utf-8") as f:
        return {slug(m.group(1)) for m in re.finditer(r"^#+ (.*)$", f.read(), re.M)}


def check_links(path):
    with open(path, encoding="utf-8") as f:
        text = f.read()
    text = re.sub(r"```.*?```", "", text, flags=re.S)  # links inside code are not links
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+:", target):
            continue
        file, _, frag = target.partition("#")
        dest = os.path.normpath(os.path.join(os.path.dirname(path), file)) if file else path
        counts["links"] += 1
        if not os.path.exists(dest):
            failures.append("%s: link to %s: no such file" % (path, target))
        elif frag and dest.endswith(".md") and frag not in anchors(dest):
            failures.append("%s: link to %s: no such heading in %s" % (path, target, dest))


def check_no_outside_design():
    """No file points at the shared folder beside the repository or at the design document by its file name."""
    needles = ("../" + "shared", "DESIGN" + ".md")
    for root, dirs, files in os.walk("."):
        dirs[:] = [d for d in dirs if not d.startswith(("build", ".git"))]
        for name in files:
            path = os.path.join(root, name)
            try:
                with open(path, encoding="utf-8") as f:
                    text = f.read()
            except (UnicodeDecodeError, OSError):
                continue
            for needle in needles:
                if needle in text:
                    failures.append("%s: points outside the repository ('%s'): docs/design.md is the design" %
                                    (path, needle))


for path in docs:
    for kind, first, text in blocks(path):
        counts[kind] += 1
        with tempfile.TemporaryDirectory(prefix="npg_docs_") as work:
            {"npg": check_block, "npg-error": check_error_block, "console": check_console}[kind](path, first, text,
                                                                                                work)

# Folders whose files another folder's README lists (a test suite's parts in tests/README.md, the
# benchmark's data in bench/README.md); data folders (tests/bad, tests/programs, pictures) are not
# code and are left out.
LISTED_BY = {"tests/support": "tests/README.md", "tests/api": "tests/README.md", "tests/cli": "tests/README.md",
             "tests/python": "tests/README.md", "tests/hostile": "tests/README.md", "tests/fuzz": "tests/README.md",
             "tests/mpi": "tests/README.md", "tests/install": "tests/README.md", "bench/interp": "bench/README.md"}


def listed(name, text):
    """Whether a README names file `name`: by its name, or as half of a pair `stem.c/.h`, `stem.h/.c`."""
    stem, ext = os.path.splitext(name)
    pair = {".c": [stem + ".h/.c"], ".h": [stem + ".c/.h"]}.get(ext, [])
    return name in text or any(p in text for p in pair)


def check_map():
    """Each folder of code opens with a README that names every file it holds (the map a
    newcomer reads: kept true when a file is added, moved or removed); an index README
    names each sub-folder."""
    folders = ["ir", "include", "scripts", "cmake", "docs", "bench", "tests"] + sorted(glob.glob("backends/*/")) + \
        sorted(glob.glob("compiler/*/")) + sorted(glob.glob("stdlib/*/")) + sorted(glob.glob("examples/*/")) + \
        sorted(LISTED_BY)
    indexes = {"backends": "backends/*/", "compiler": "compiler/*/", "stdlib": "stdlib/*/", "examples": "examples/*/"}
    readmes = []
    for folder in (f.rstrip("/") for f in folders):
        readme = LISTED_BY.get(folder, os.path.join(folder, "README.md"))
        if not os.path.exists(readme):
            failures.append("%s: no README.md listing its files" % folder)
            continue
        if readme not in readmes:
            readmes.append(readme)
        with open(readme, encoding="utf-8") as f:
            text = f.read()
        for name in sorted(os.listdir(folder)):
            if name != "README.md" and os.path.isfile(os.path.join(folder, name)) and "`" not in name:
                counts["map"] += 1
                if not listed(name, text):
                    failures.append("%s: %s/%s is not in the folder's list" % (readme, folder, name))
    for index, pattern in indexes.items():
        readme = os.path.join(index, "README.md")
        readmes.append(readme)
        with open(readme, encoding="utf-8") as f:
            text = f.read()
        for sub in sorted(glob.glob(pattern)):
            if os.path.basename(sub.rstrip("/")) + "/" not in text:
                failures.append("%s: the sub-folder %s is not in the index" % (readme, sub))
    return readmes


for path in docs + ["README.md"] + check_map():
    check_links(path)
check_no_outside_design()

print("docs: %d programs, %d refused programs, %d sessions, %d stated results and %d links checked in %s; "
      "%d files found in their folder's README" %
      (counts["npg"], counts["npg-error"], counts["console"], counts["expectations"], counts["links"],
       ", ".join(docs), counts["map"]))
if counts["npg"] == 0:
    failures.append("no ```npg block found in docs/*.md")
for f in failures:
    print("FAIL:", f)
sys.exit(1 if failures else 0)
