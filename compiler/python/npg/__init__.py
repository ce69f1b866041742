"""npg: the compiler for non-polynomial Galerkin projection, from Python.

    prog = npg.compile("prog.npg")            # or the program's text
    full = prog.full(params={...})            # full(x=array) -> {output: array}
    tr = npg.Trainer(full, energy=0.999)      # tr.add(x=array) per sample
    model = tr.finish("MODEL")                # the same model npgc train writes
    red = model.reduced()                     # red(x=array) -> {output: coordinates}
    y = red.lift("y")                         # B y-hat, shaped like y

The module is written in C over the library's npg.h (compiler/python/);
README.md "From Python" documents it.
"""
import os as _os

from ._npg import (Error, CompileError, Program, Full, Trainer, Model, Reduced,  # noqa: F401
                   compile, load)
from . import _npg

# The stdlib modules (`use geometry`) installed beside the package; a build
# tree has none and the library finds the source tree's.
_std = _os.path.join(_os.path.dirname(__file__), "stdlib")
if _os.path.isdir(_os.path.join(_std, "npg")):
    _npg._set_std_dir(_std)

__all__ = ["Error", "CompileError", "Program", "Full", "Trainer", "Model", "Reduced", "compile", "load"]
