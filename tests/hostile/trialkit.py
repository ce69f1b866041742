"""trialkit.py — what the hostile trials (corpus.py, trial2.py, trial3.py) share: the marks of a
sanitizer report, the build's CMake cache, the manifest checksum, and the C API drivers' build."""
import os
import subprocess

SANITIZER_MARKS = ("ERROR: AddressSanitizer", "ERROR: LeakSanitizer", "runtime error:", "ERROR: UndefinedBehavior",
                   "AddressSanitizer:DEADLYSIGNAL", "ThreadSanitizer")


def cmake_cache(build, key):
    """The value of `key` in BUILD/CMakeCache.txt ("" when absent)."""
    try:
        with open(os.path.join(build, "CMakeCache.txt")) as f:
            for line in f:
                if line.startswith(key + ":"):
                    return line.split("=", 1)[1].strip()
    except OSError:
        pass
    return ""


def sanitized(build):
    """Whether BUILD is the sanitizer build (its drivers must be built the same way)."""
    return cmake_cache(build, "NPG_SANITIZE").upper() in ("ON", "1", "TRUE", "YES")


def fnv1a64(data):
    """The manifest's checksum (backends/model/model_store.c)."""
    h = 0xcbf29ce484222325
    for byte in data:
        h = ((h ^ byte) * 0x100000001b3) & 0xFFFFFFFFFFFFFFFF
    return h


def build_api(src, build, driver, out):
    """Compile the C API driver SRC/DRIVER against the build's libnpg into OUT (sanitized like it)."""
    cc = ["cc", "-std=c11", "-O1", "-g", "-I", os.path.join(src, "include"), os.path.join(src, driver),
          "-o", out, "-L", build, "-Wl,-rpath," + build, "-lnpg", "-ltcc", "-ldl", "-lm"]
    if sanitized(build):
        cc[1:1] = ["-fsanitize=address,undefined"]
    p = subprocess.run(cc, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    if p.returncode != 0:
        raise SystemExit("cannot build the API driver: %s" % p.stderr.decode()[:2000])
