"""Fixtures of the npg module's tests: the repository root, the npgc of the
same build (NPG_NPGC, set by ctest; else build/npgc), and a runner."""
import os
import pathlib
import subprocess

import pytest

ROOT = pathlib.Path(os.environ.get("NPG_SOURCE_DIR", pathlib.Path(__file__).resolve().parents[2]))


@pytest.fixture(scope="session")
def root():
    return ROOT


@pytest.fixture(scope="session")
def npgc():
    exe = pathlib.Path(os.environ.get("NPG_NPGC", ROOT / "build" / "npgc"))
    if not exe.is_file():
        pytest.fail(f"npgc not found at {exe} (set NPG_NPGC)")

    def run(*args, check=True):
        r = subprocess.run([str(exe), *map(str, args)], cwd=ROOT, capture_output=True, text=True)
        if check and r.returncode != 0:
            pytest.fail(f"npgc {' '.join(map(str, args))} failed ({r.returncode}):\n{r.stderr}")
        return r

    return run
