/* program.c — npg.compile and the Program type: the compiled program, its
 * check report as Python objects, and the factory of full evaluators. */
#include "npgpy.h"

#include <stdio.h>
#include <stdlib.h>
#include <sys/stat.h>

/* A path when it names a file, or when it ends in .npg and holds no newline
 * (so a missing file is reported as such); source text otherwise. */
static bool looks_like_path(const char *s) {
  struct stat st;
  if (strchr(s, '\n')) return false;
  if (stat(s, &st) == 0) return true;
  size_t n = strlen(s);
  return n >= 4 && strcmp(s + n - 4, ".npg") == 0;
}

PyObject *npgpy_compile(PyObject *self, PyObject *args, PyObject *kw) {
  static char *kwlist[] = {"path_or_source", "name", "std_dir", NULL};
  PyObject *what, *name = Py_None, *std = Py_None;
  if (!PyArg_ParseTupleAndKeywords(args, kw, "O|OO:compile", kwlist, &what, &name, &std)) return NULL;
  PyObject *text = NULL, *path = NULL, *stdb = NULL;
  bool pathlike = !PyUnicode_Check(what);
  if (pathlike) { /* os.PathLike */
    if (!PyUnicode_FSDecoder(what, &text)) return NULL;
  } else {
    text = Py_NewRef(what);
  }
  Py_ssize_t slen = 0;
  const char *s = PyUnicode_AsUTF8AndSize(text, &slen);
  if (!s) goto fail;
  /* The C side reads up to the first NUL: "vec.npg\0x" would compile vec.npg (as open() does, refuse). */
  if (strlen(s) != (size_t)slen) {
    PyErr_Format(PyExc_ValueError, "compile: the %s holds a NUL byte at character %zu",
                 pathlike || looks_like_path(s) ? "path" : "source", strlen(s));
    goto fail;
  }
  NpgOptions opt = {0};
  const char *src = NULL;
  if (pathlike || looks_like_path(s)) {
    path = Py_NewRef(text);
  } else {
    src = s;
    path = name == Py_None ? PyUnicode_FromString("<string>") : PyObject_Str(name);
    if (!path) goto fail;
  }
  if (std != Py_None) {
    if (!PyUnicode_FSConverter(std, &stdb)) goto fail;
    opt.std_dir = PyBytes_AS_STRING(stdb);
  } else {
    opt.std_dir = npgpy_std_dir;
  }
  opt.source = src;
  const char *cpath = npgpy_utf8(path);
  if (!cpath) goto fail;
  NpgProgram *p;
  Py_BEGIN_ALLOW_THREADS
  p = npg_compile(cpath, &opt);
  Py_END_ALLOW_THREADS
  if (!p) {
    PyErr_NoMemory();
    goto fail;
  }
  if (!npg_ok(p)) {
    npgpy_raise(npgpy_CompileError, npg_error(p));
    npg_free(p);
    goto fail;
  }
  ProgramObject *po = PyObject_New(ProgramObject, &npgpy_ProgramType);
  if (!po) {
    npg_free(p);
    goto fail;
  }
  po->p = p;
  po->path = path;
  po->report = NULL;
  po->sym = npgpy_symbols(p, &po->nsym);
  Py_DECREF(text);
  Py_XDECREF(stdb);
  if (!po->sym) {
    Py_DECREF(po);
    return NULL;
  }
  return (PyObject *)po;
fail:
  Py_XDECREF(text);
  Py_XDECREF(path);
  Py_XDECREF(stdb);
  return NULL;
}

static void program_dealloc(ProgramObject *self) {
  npg_free(self->p); /* nothing else points into it by now: every user holds a reference */
  PyMem_Free(self->sym);
  Py_XDECREF(self->path);
  Py_XDECREF(self->report);
  Py_TYPE(self)->tp_free((PyObject *)self);
}

/* The report of `npgc check` (json: the dict of `--json`). */
static PyObject *report_text(ProgramObject *self, bool json) {
  char *buf = NULL;
  size_t len = 0;
  FILE *out = open_memstream(&buf, &len);
  if (!out) return PyErr_NoMemory();
  npg_report(self->p, out, json);
  fclose(out);
  PyObject *s = PyUnicode_DecodeUTF8(buf, (Py_ssize_t)len, "replace");
  free(buf);
  return s;
}

static PyObject *report_dict(ProgramObject *self) {
  if (self->report) return self->report;
  PyObject *text = report_text(self, true), *json = text ? PyImport_ImportModule("json") : NULL;
  if (json) self->report = PyObject_CallMethod(json, "loads", "O", text);
  Py_XDECREF(json);
  Py_XDECREF(text);
  return self->report;
}

static PyObject *get_report_key(ProgramObject *self, void *key) {
  PyObject *r = report_dict(self);
  if (!r) return NULL;
  PyObject *v = PyDict_GetItemString(r, (const char *)key);
  if (!v) return PyList_New(0);
  return Py_NewRef(v);
}

static PyObject *get_report(ProgramObject *self, void *unused) {
  PyObject *r = report_dict(self);
  return r ? Py_NewRef(r) : NULL;
}

static PyObject *get_path(ProgramObject *self, void *unused) { return Py_NewRef(self->path); }

static const char *kind_name(NpgKind k) {
  switch (k) {
  case NPG_PARAM: return "param";
  case NPG_INPUT: return "input";
  case NPG_EXTERN: return "extern";
  case NPG_STAGE: return "stage";
  case NPG_OP: return "op";
  }
  return "?";
}

/* Every declared symbol: name, kind, output, dims (names), static shape. */
static PyObject *get_symbols(ProgramObject *self, void *unused) {
  PyObject *list = PyList_New(self->nsym);
  for (int i = 0; list && i < self->nsym; i++) {
    const NpgSymbol *s = &self->sym[i];
    PyObject *dims = PyTuple_New(s->ndims), *stat = PyTuple_New(s->nstatic);
    for (int k = 0; dims && k < s->ndims; k++) PyTuple_SET_ITEM(dims, k, PyUnicode_FromString(s->dims[k]));
    for (int k = 0; stat && k < s->nstatic; k++) PyTuple_SET_ITEM(stat, k, PyLong_FromLong(s->shape[k]));
    PyObject *d = dims && stat ? Py_BuildValue("{s:s,s:s,s:O,s:O,s:O}", "name", s->name, "kind", kind_name(s->kind),
                                               "output", s->output ? Py_True : Py_False, "dims", dims, "static", stat)
                               : NULL;
    Py_XDECREF(dims);
    Py_XDECREF(stat);
    if (!d) {
      Py_CLEAR(list);
      break;
    }
    PyList_SET_ITEM(list, i, d);
  }
  return list;
}

static PyObject *program_check(ProgramObject *self, PyObject *unused) { return report_text(self, false); }

static PyObject *program_full(ProgramObject *self, PyObject *args, PyObject *kw) {
  static char *kwlist[] = {"params", "backend", NULL};
  PyObject *params = Py_None;
  const char *backend = "auto";
  if (!PyArg_ParseTupleAndKeywords(args, kw, "|Os:full", kwlist, &params, &backend)) return NULL;
  return npgpy_full_new(self, params, backend);
}

static PyObject *program_repr(ProgramObject *self) { return PyUnicode_FromFormat("<npg.Program %R>", self->path); }

static PyGetSetDef program_getset[] = {
  {"path", (getter)get_path, NULL, "the file compiled, or the name of the source text", NULL},
  {"stages", (getter)get_report_key, NULL, "the stages of the check report (npgc check --json): list of dicts",
   "stages"},
  {"classes", (getter)get_report_key, NULL, "the basis classes of the check report: list of dicts", "classes"},
  {"inputs", (getter)get_report_key, NULL, "the inputs of the check report: list of dicts", "inputs"},
  {"report", (getter)get_report, NULL, "the whole check report (npgc check --json) as a dict", NULL},
  {"symbols", (getter)get_symbols, NULL, "params, quantities and operators as declared", NULL},
  {NULL},
};

static PyMethodDef program_methods[] = {
  {"check", (PyCFunction)program_check, METH_NOARGS, "check() -> str: the npgc check report as text"},
  {"full", (PyCFunction)(void (*)(void))program_full, METH_VARARGS | METH_KEYWORDS,
   "full(params=None, backend='auto') -> Full\n\n"
   "A full evaluator: its generated C compiled by the system compiler ('cc', -O3, kept in\n"
   "the cache of compiled evaluators) or by libtcc ('tcc', in memory); 'auto' is $NPG_JIT\n"
   "when set, else cc where installed, else libtcc (npgc's --jit).\n"
   "params: a dict name -> array (int params as integer arrays), or a directory holding\n"
   "<param>.npy files."},
  {NULL},
};

PyTypeObject npgpy_ProgramType = {
  PyVarObject_HEAD_INIT(NULL, 0)
  .tp_name = "npg.Program",
  .tp_basicsize = sizeof(ProgramObject),
  .tp_dealloc = (destructor)program_dealloc,
  .tp_repr = (reprfunc)program_repr,
  .tp_flags = Py_TPFLAGS_DEFAULT,
  .tp_doc = "A compiled .npg program (npg.compile).",
  .tp_methods = program_methods,
  .tp_getset = program_getset,
};
