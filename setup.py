"""Builds the Python module npg with the project's CMake (the module links
libnpg's objects, which only CMake knows how to build: the re2c lexer, the
embedded ABI header, the patched libtcc). `pip install --no-build-isolation .`
runs it; the packages of scripts/setup.sh are all it needs, no network.

The CMake build lives in build-pip/ (setuptools' build_base), apart from the
developers' build/."""
import os
import pathlib
import shutil
import subprocess
import sys

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

ROOT = pathlib.Path(__file__).resolve().parent


class CMakeBuild(build_ext):
    def build_extension(self, ext):
        build = pathlib.Path(self.build_temp).resolve() / "cmake"
        config = ["cmake", "-S", str(ROOT), "-B", str(build), "-DCMAKE_BUILD_TYPE=Release",
                  f"-DPython3_EXECUTABLE={sys.executable}", "-DNPG_PYTHON=ON"]
        subprocess.check_call(config)
        jobs = os.environ.get("CMAKE_BUILD_PARALLEL_LEVEL", str(os.cpu_count() or 1))
        subprocess.check_call(["cmake", "--build", str(build), "--target", "npg_python", "-j", jobs])
        built = list((build / "python" / "npg").glob("_npg*.so"))
        if len(built) != 1:
            sys.exit(f"setup.py: the CMake build made {len(built)} modules in {build}/python/npg, not one "
                     "(is python3-dev installed for this interpreter? CMake says so above)")
        dest = pathlib.Path(self.get_ext_fullpath(ext.name))
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(built[0], dest)
        # the stdlib modules (`use geometry`) beside the package: npg/__init__.py finds them
        std = dest.parent / "stdlib" / "npg"
        std.mkdir(parents=True, exist_ok=True)
        for f in (ROOT / "stdlib" / "npg").glob("*.npg"):
            shutil.copyfile(f, std / f.name)


# setuptools' own files (egg-info) go there too, not into the source tree
(ROOT / "build-pip").mkdir(exist_ok=True)
setup(
    packages=["npg"],
    package_dir={"npg": "compiler/python/npg"},
    ext_modules=[Extension("npg._npg", sources=[])],
    cmdclass={"build_ext": CMakeBuild},
    options={"build": {"build_base": "build-pip"}, "egg_info": {"egg_base": "build-pip"}},
)
