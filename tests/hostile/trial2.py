#!/usr/bin/python3
"""trial2.py BUILD_DIR [NAME...] — the second hostile trial (issue 24's goal).

Cases NOT in corpus.py or the CLI/API tests, as a hostile new user types
them, against every face of npg: npgc (check, emit, train, eval, verify,
bench, plot, tune), npg.h (tests/hostile/trial2_api.c, compiled here against
the build's libnpg), the Python module and the three applications.

Each case is a command with its expectation: the exit status, a substring
of stderr (or of stdout for the API and Python drivers), and, where a result
is produced, a check of that result against numpy (a quiet wrong answer is
a failure), or of the files the command must not lose or replace. A case
also fails when it is killed by a signal, a sanitizer reports, it runs past
its timeout, or it exits 0 on bad input. "either" cases accept a clear
refusal or a correct value, nothing else.

KNOWN_FAILURES lists the cases that still fail, each with its reason; they
run and are reported but do not fail the test (and say so once they pass).

With NAME arguments only the cases whose name contains one of them run;
NPG_TRIAL_VERBOSE=1 prints every case's outcome.
"""
import hashlib
import math
import os
import random
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

import trialkit
from trialkit import SANITIZER_MARKS, fnv1a64, sanitized

np.seterr(all="ignore")   # the recipes overflow on purpose (1e300 data); npg must say so, numpy need not

BUILD = os.path.abspath(sys.argv[1])
SRC = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
NPGC = os.path.join(BUILD, "npgc")
ONLY = sys.argv[2:]
VERBOSE = os.environ.get("NPG_TRIAL_VERBOSE") == "1"
TIMEOUT = 90


SANITIZED = sanitized(BUILD)
W = tempfile.mkdtemp(prefix="npg_trial2_")
os.chmod(W, 0o755)
CASES = []
KNOWN_FAILURES = {   # none left: the 16 of the first run were fixed (issue 24)
}


def case(name, argv, status=1, msg="", check=None, stdin=None, timeout=None, env=None, cwd=None, stream="err",
         before=None):
    """argv[0]: 'npgc', 'api', 'py', an application's name, or a path. `msg`: a substring of stderr
    (stdout with stream='out'); '=' first: the whole first line. `status` None: any non-zero but not a
    signal (a refusal); 'either': 0 with check() passing, or non-zero with an 'error' message.
    `check(proc)` returns a problem or None. `before()` runs just before the command."""
    CASES.append(dict(name=name, argv=argv, status=status, msg=msg, check=check, stdin=stdin,
                      timeout=timeout or TIMEOUT, env=env, cwd=cwd or W, stream=stream, before=before))


def path(*parts):
    return os.path.join(W, *parts)


def write(rel, data, mode=0o644):
    p = path(rel)
    os.makedirs(os.path.dirname(p), exist_ok=True)
    with open(p, "wb" if isinstance(data, bytes) else "w") as f:
        f.write(data)
    os.chmod(p, mode)
    return p


def digest(p):
    h = hashlib.sha256()
    for root, dirs, files in sorted(os.walk(p)) if os.path.isdir(p) else [("", [], [p])]:
        dirs.sort()
        for f in sorted(files):
            q = os.path.join(root, f)
            h.update(q[len(p):].encode())
            if os.path.islink(q):
                h.update(b"link:" + os.readlink(q).encode())
            elif os.path.isfile(q):
                with open(q, "rb") as fh:
                    h.update(fh.read())
    return h.hexdigest()


def kept(*rels):
    """A check: every path in `rels` has the bytes it had when the case was made."""
    snap = {r: digest(path(r)) for r in rels}

    def check(proc):
        for r, d in snap.items():
            if not os.path.lexists(path(r)):
                return "%s was lost" % r
            if digest(path(r)) != d:
                return "%s was changed" % r
        return None
    return check


def both(*checks):
    def check(proc):
        for c in checks:
            if c:
                prob = c(proc)
                if prob:
                    return prob
        return None
    return check


def close(got, want, rtol=1e-10, atol=0.0, what="y"):
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    if got.shape != want.shape:
        return "%s has shape %s, numpy says %s" % (what, got.shape, want.shape)
    if not np.all(np.isfinite(got)):
        return "%s holds non-finite values" % what
    scale = max(1.0, float(np.max(np.abs(want)))) if want.size else 1.0
    err = float(np.max(np.abs(got - want))) if want.size else 0.0
    if err > rtol * scale + atol:
        return "%s differs from numpy by %.3e (scale %.3e)" % (what, err, scale)
    return None


def out_equals(rel, want, rtol=1e-10, atol=0.0):
    def check(proc):
        p = path(rel)
        if not os.path.exists(p):
            return "%s was not written" % rel
        return close(np.load(p), want, rtol, atol, rel)
    return check


# ------------------------------------------------------------------ programs and data

RNG = np.random.default_rng(2024)
VEC = "dim N\nparam rho : real[N]\ninput x : real[N]\noutput y[i:N] = rho[i] * x[i] * x[i] + x[i]\n"
TWO = "dim N\ninput x : real[N]\ninput z : real[N]\noutput y[i:N] = x[i] * z[i]\n"
X = 1 + RNG.random((12, 5))
RHO = 1 + RNG.random(5)
XT = 1 + RNG.random((4, 5))


def vec_y(x, rho=RHO):
    return rho * x * x + x


def data_dir(rel, arrays):
    os.makedirs(path(rel), exist_ok=True)
    for name, a in arrays.items():
        if isinstance(a, bytes):
            write(os.path.join(rel, name + ".npy"), a)
        else:
            np.save(path(rel, name + ".npy"), a)
    return rel


def npgc_ok(*argv):
    p = subprocess.run([NPGC] + list(argv), cwd=W, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    if p.returncode != 0:
        raise SystemExit("fixture failed: npgc %s\n%s" % (" ".join(argv), p.stderr.decode()))


def fixtures():
    write("vec.npg", VEC)
    write("two.npg", TWO)
    data_dir("D", {"rho": RHO, "x": X})
    data_dir("T", {"rho": RHO, "x": XT})
    npgc_ok("train", "vec.npg", "D", "-o", "M")


# ------------------------------------------------------------------ 1. expressions against numpy

def expr_program(name, expr, n=3):
    write("expr/%s.npg" % name, "input x : real[%d]\noutput y = %s\n" % (n, expr))


XE = 1 + RNG.random((4, 3))   # inputs in [1, 2): every denominator and root base positive
data_dir("XE", {"x": XE})


def expr_case(name, expr, pyexpr, status=0, msg="", n=3, either=False, rtol=1e-9):
    """`pyexpr`: the same expression in Python over x (a row of XE), or None for a refusal."""
    expr_program(name, expr, n)
    argv = ["npgc", "eval", "expr/%s.npg" % name, "--full", "XE", "XE", "-o", "out/expr_" + name]
    if pyexpr is None:
        case("expr_" + name, argv, status, msg)
        return
    want = np.array([np.asarray(eval(pyexpr, {"np": np, "math": math}, {"x": xk}), dtype=float) for xk in XE])
    case("expr_" + name, argv, "either" if either else 0, msg, check=out_equals("out/expr_%s/y.npy" % name, want, rtol))


def expression_cases():
    ops = ["+", "-", "*", "/"]
    # precedence and associativity: a op1 b op2 c for every pair, with literals and inputs
    for i, o1 in enumerate(ops):
        for j, o2 in enumerate(ops):
            expr_case("prec_%d%d" % (i, j), "x[0] %s x[1] %s x[2]" % (o1, o2), "x[0] %s x[1] %s x[2]" % (o1, o2))
            expr_case("prec_lit_%d%d" % (i, j), "3 %s x[1] %s 2" % (o1, o2), "3 %s x[1] %s 2" % (o1, o2))
    for i, o in enumerate(ops):
        expr_case("pow_left_%d" % i, "x[0]^2 %s x[1]" % o, "x[0]**2 %s x[1]" % o)
        expr_case("pow_right_%d" % i, "x[0] %s x[1]^3" % o, "x[0] %s x[1]**3" % o)
        expr_case("neg_pow_%d" % i, "-x[0]^2 %s x[1]" % o, "-x[0]**2 %s x[1]" % o)
    expr_case("pow_chain_right_assoc", "x[0]^2^3", "x[0]**(2**3)", either=True)
    expr_case("pow_literal_chain", "2^3^2 * x[0]", "2**(3**2) * x[0]", either=True)
    expr_case("double_minus", "x[0] - -x[1]", "x[0] - -x[1]", either=True)
    expr_case("plus_minus", "x[0] + -x[1]", "x[0] + -x[1]", either=True)
    expr_case("minus_times_minus", "-x[0] * -x[1]", "-x[0] * -x[1]", either=True)
    expr_case("unary_plus", "+x[0]", "+x[0]", either=True)
    expr_case("neg_exponent_bare", "x[0]^-1", "x[0]**-1", either=True)
    expr_case("neg_exponent_paren", "x[0]^(-1)", "x[0]**-1")
    expr_case("pow_zero", "x[0]^0 + x[1]", "1 + x[1]")
    expr_case("pow_one_half_of_square", "(x[0]^2)^(1/2)", "x[0]", rtol=1e-12)
    expr_case("pow_rational_reducible", "x[0]^(2/4)", "x[0]**0.5")
    expr_case("pow_rational_negative_den", "x[0]^(1/-2)", "x[0]**-0.5", either=True)
    expr_case("pow_three_halves", "x[0]^(3/2) * x[1]", "x[0]**1.5 * x[1]")
    expr_case("pow_minus_three_halves", "(x[0] + x[1])^(-3/2)", "(x[0] + x[1])**-1.5")
    expr_case("pow_two_thirds", "x[2]^(2/3)", "x[2]**(2/3)")
    expr_case("pow_big_integer", "x[0]^40", "x[0]**40", rtol=1e-9)
    expr_case("sqrt_of_sum", "sqrt(x[0]*x[0] + x[1]*x[1])", "math.sqrt(x[0]*x[0] + x[1]*x[1])")
    expr_case("sqrt_nested", "sqrt(sqrt(x[0]))", "x[0]**0.25")
    expr_case("div_chain", "x[0] / x[1] / x[2]", "x[0] / x[1] / x[2]")
    expr_case("div_of_div", "x[0] / (x[1] / x[2])", "x[0] / (x[1] / x[2])")
    expr_case("recip_of_sum_of_recips", "1 / (1 / x[0] + 1 / x[1])", "1 / (1 / x[0] + 1 / x[1])")
    expr_case("pi_literal", "pi * x[0]", "math.pi * x[0]")
    expr_case("decimal_forms", "1. * x[0] + .5 * x[1] + 2e0 * x[2] + 1E-1", "x[0] + .5*x[1] + 2*x[2] + 0.1", either=True)
    expr_case("exponent_literal_tiny", "x[0] * 1e-300 * 1e300", "x[0] * 1e-300 * 1e300", either=True)
    expr_case("literal_denormal", "x[0] + 4.9e-324", "x[0] + 4.9e-324")
    expr_case("literal_underflow", "x[0] + 1e-400", "x[0] + 1e-400", either=True)
    expr_case("literal_max_double", "x[0] * 1.7976931348623157e308 / 1e308", "x[0] * 1.7976931348623157e308 / 1e308",
              either=True)
    expr_case("literal_fold_overflow", "x[0] * (1e200 * 1e200)", None, 1, "error")
    expr_case("literal_fold_zero_div", "x[0] * (1 / (2 - 2))", None, 1, "division by zero")
    expr_case("integer_2_53", "x[0] * 9007199254740992", "x[0] * 9007199254740992.0")
    expr_case("integer_2_53_plus_1", "x[0] * 9007199254740993", None, 1, "2^53")
    expr_case("vector_output", "[x[0] + x[1], x[1] * x[2], x[2] / x[0]]", "[x[0] + x[1], x[1] * x[2], x[2] / x[0]]")
    expr_case("vector_nested_sum", "[x[0], x[1]] + [x[2], x[0]]", "[x[0] + x[2], x[1] + x[0]]", either=True)
    expr_case("vector_times_scalar", "x[0] * [1, 2, 3]", "[x[0], 2 * x[0], 3 * x[0]]")
    expr_case("literal_sum", "sum(k = 0..2, x[k] * (k + 1))", "x[0] + 2 * x[1] + 3 * x[2]")
    expr_case("literal_sum_nested", "sum(k = 0..2, sum(l = 0..2, x[k] * x[l]))", "sum(x)**2")
    expr_case("sum_single_term", "sum(k = 1..1, x[k])", "x[1]")
    expr_case("if_on_index", "sum(k = 0..2, if(k == 1, x[k], 2 * x[k]))", "2 * x[0] + x[1] + 2 * x[2]")
    expr_case("delta_literal", "sum(k = 0..2, delta(k, 2) * x[k])", "x[2]")
    expr_case("fn_shadow", "g(x[1])\nfn g(x) = x * x", "x[1] * x[1]", either=True)
    expr_case("whitespace_tabs", "x[0]\t*\tx[1]", "x[0] * x[1]")
    expr_case("whitespace_formfeed", "x[0] *\fx[1]", "x[0] * x[1]", either=True)
    expr_case("whitespace_vtab", "x[0] *\vx[1]", "x[0] * x[1]", either=True)
    expr_case("continuation_newline", "(x[0] +\n x[1])", "x[0] + x[1]", either=True)
    expr_case("comment_after", "x[0] # a comment * 100", "x[0]")
    expr_case("crlf_lines", "x[0] + x[1]\r", "x[0] + x[1]", either=True)
    # random fully parenthesized trees: folding, expansion and cancellation against numpy
    rnd = random.Random(7)

    def tree(d, positive):
        if d == 0 or rnd.random() < 0.25:
            if rnd.random() < 0.7:
                k = rnd.randrange(3)
                return "x[%d]" % k, "x[%d]" % k
            v = rnd.choice([1, 2, 3, 0.5, 1.25, 7])
            return repr(v), repr(v)
        op = rnd.choice(["+", "*", "/", "^", "s", "-"] if not positive else ["+", "*", "/", "^", "s"])
        a, pa = tree(d - 1, positive)
        if op == "s":
            return "sqrt(%s)" % a if positive else "(%s)" % a, "(%s)**0.5" % pa if positive else "(%s)" % pa
        if op == "^":
            e = rnd.choice(["2", "3", "(1/2)", "(-1)", "(3/2)", "(-1/2)"]) if positive else rnd.choice(["2", "3"])
            return "(%s)^%s" % (a, e), "(%s)**(%s)" % (pa, e.replace("/", "/"))
        b, pb = tree(d - 1, positive or op == "/")
        if op == "/":
            return "(%s) / (%s)" % (a, b), "(%s) / (%s)" % (pa, pb)
        return "(%s) %s (%s)" % (a, op, b), "(%s) %s (%s)" % (pa, op, pb)
    for k in range(60):
        e, pe = tree(4, k % 2 == 0)
        if "x[" not in e:   # a constant output is refused (make it a param): keep every tree varying
            e, pe = "(%s) + x[0]" % e, "(%s) + x[0]" % pe
        expr_case("random_%02d" % k, e, pe, rtol=1e-8)


# ------------------------------------------------------------------ 2. front end stress

def prog_case(name, text, status, msg, args=()):
    p = "fe/%s.npg" % name
    write(p, text)
    case("fe_" + name, ["npgc", "check", p] + list(args), status, msg)


def front_end_cases():
    head = "input x : real[2]\noutput y = "
    prog_case("utf8_identifier", "input x\u00e9 : real[2]\noutput y = x\u00e9[0]\n", 1, "non-ASCII")
    prog_case("utf8_in_comment", "# r\u00e9sum\u00e9 \u2014 \U0001F600\n" + head + "x[0]\n", 0, "")
    prog_case("bom", "\ufeff" + head + "x[0]\n", 1, "")
    prog_case("nbsp", head + "x[0]\u00a0+ x[1]\n", 1, "non-ASCII")
    prog_case("cr_only", head.replace("\n", "\r") + "x[0]\r", "either", "")
    prog_case("tab_indent", "\tinput x : real[2]\n\toutput y = x[0]\n", "either", "")
    prog_case("trailing_no_newline", head + "x[0]", 0, "")
    prog_case("only_whitespace", " \t\n\n  \n", 1, "no output")
    prog_case("keyword_as_name", "input input : real[2]\noutput y = input[0]\n", None, "")
    prog_case("name_pi", "input pi : real[2]\noutput y = pi[0]\n", "either", "")
    prog_case("name_sqrt", "input sqrt : real[2]\noutput y = sqrt[0]\n", "either", "")
    prog_case("name_128", "input " + "a" * 128 + " : real[2]\noutput y = " + "a" * 128 + "[0]\n", 0, "")
    prog_case("name_129", "input " + "a" * 129 + " : real[2]\noutput y = " + "a" * 129 + "[0]\n", 1, "at most 128")
    prog_case("name_digit_first", "input 1x : real[2]\noutput y = 1x[0]\n", 1, "error")
    prog_case("name_underscore", "input _ : real[2]\noutput y = _[0]\n", "either", "")
    prog_case("deep_if", "dim N\ninput x : real[N]\noutput y[i:N] = " + "if(i == 0, " * 300 + "x[i]" + ", x[i])" * 300 + "\n",
              1, "nested too deeply")
    prog_case("deep_sqrt", head + "sqrt(" * 300 + "x[0]" + ")" * 300 + "\n", 1, "nested too deeply")
    prog_case("deep_index", "dim N\nparam e : int[N]\ninput x : real[N]\noutput y[i:N] = x[" + "e[" * 200 + "i" +
              "]" * 200 + "]\n", 1, "too deeply")
    prog_case("deep_sum_nesting", "dim N\ninput x : real[N]\noutput y = " +
              "".join("sum(k%d = 0..1, " % i for i in range(40)) + "x[0]" + ")" * 40 + "\n", 1, "error")
    prog_case("sum_expansion_bounded", "input x : real[2]\noutput y = " +
              "".join("sum(k%d = 0..99, " % i for i in range(5)) + "x[0]" + ")" * 5 + "\n", 1, "error")
    prog_case("fn_many_args", "fn f(" + ", ".join("a%d" % i for i in range(300)) + ") = a0\n" + head + "f(" +
              ", ".join(["x[0]"] * 300) + ")\n", "either", "")
    prog_case("fn_wrong_arity", "fn f(a, b) = a * b\n" + head + "f(x[0])\n", 1, "error")
    prog_case("fn_defined_twice", "fn f(a) = a\nfn f(a) = 2 * a\n" + head + "f(x[0])\n", 1, "error")
    prog_case("fn_named_like_input", "fn x(a) = a\n" + head + "x(x[0])\n", 1, "error")
    prog_case("dim_twice", "dim N, N\ninput x : real[N]\noutput y[i:N] = x[i]\n", 1, "error")
    prog_case("index_var_twice", "dim N\ninput x : real[N]\noutput y[i:N, i:N] = x[i]\n", 1, "error")
    prog_case("index_var_unused_dim", "dim N, M\ninput x : real[N]\noutput y[i:N, j:M] = x[i]\n", "either", "")
    prog_case("too_few_indices", "dim N\ninput x : real[N, 3]\noutput y[i:N] = x[i]\n", "either", "")
    prog_case("too_many_indices", "dim N\ninput x : real[N]\noutput y[i:N] = x[i, 0]\n", 1, "error")
    prog_case("negative_literal_index", head + "x[-1]\n", 1, "error")
    prog_case("fractional_index", head + "x[0.5]\n", 1, "error")
    prog_case("index_by_input", head + "x[x[0]]\n", 1, "error")
    prog_case("real_param_as_index", "dim N\nparam r : real[N]\ninput x : real[N]\noutput y[i:N] = x[r[i]]\n", 1, "error")
    prog_case("int_input", "input x : int[2]\noutput y = x[0]\n", 1, "error")
    prog_case("unknown_type", "input x : complex[2]\noutput y = x[0]\n", 1, "error")
    prog_case("missing_colon", "input x real[2]\noutput y = x[0]\n", 1, "error")
    prog_case("unclosed_bracket", "input x : real[2\noutput y = x[0]\n", 1, "error")
    prog_case("unbalanced_paren", head + "(x[0] + x[1]))\n", 1, "error")
    prog_case("empty_vector", head + "[]\n", 1, "error")
    prog_case("ragged_vector", head + "[[x[0], x[1]], [x[0]]]\n", 1, "error")
    prog_case("trailing_comma_vector", head + "[x[0], x[1],]\n", "either", "")
    prog_case("double_operator", head + "x[0] * * x[1]\n", 1, "error")
    prog_case("caret_only", head + "^\n", 1, "error")
    prog_case("if_two_args", head + "if(1 == 1, x[0])\n", 1, "error")
    prog_case("delta_three_args", "dim N\ninput x : real[N]\noutput y[i:N] = delta(i, i, i) * x[i]\n", 1, "error")
    prog_case("sqrt_two_args", head + "sqrt(x[0], x[1])\n", 1, "error")
    prog_case("solve_non_op", "dim N\ninput x : real[N]\noutput y = solve(x, x)\n", 1, "error")
    prog_case("root_zero", "dim N\nparam a : real[N, N]\ninput x : real[N]\nop M[i:N, j:N] = a[i, j]\noutput y = root(M, 0) * x\n",
              1, "error")
    prog_case("op_power_irrational", "dim N\nparam a : real[N, N]\ninput x : real[N]\nop M[i:N, j:N] = a[i, j]\n"
              "output y = M^0.3 * x\n", 1, "error")
    prog_case("op_nonsquare", "dim N, K\nparam a : real[N, K]\ninput x : real[K]\nop M[i:N, j:K] = a[i, j]\n"
              "output y = solve(M, x)\n", 1, "error")
    prog_case("op_times_wrong_dim", "dim N, K\nparam a : real[N, N]\ninput x : real[K]\nop M[i:N, j:N] = a[i, j]\n"
              "output y = M * x\n", 1, "error")
    prog_case("share_unknown", "input x : real[2]\noutput y = x[0]\nshare x, nosuch\n", 1, "nosuch")
    prog_case("share_one", "input x : real[2]\noutput y = x[0]\nshare x\n", 1, "at least two")
    prog_case("basis_cap_negative", "input x : real[2]\noutput y = x[0]\nbasis x: cap -3\n", 1, "error")
    prog_case("basis_energy_zero", "input x : real[2]\noutput y = x[0]\nbasis x: energy 0\n", 1, "error")
    prog_case("basis_energy_nan", "input x : real[2]\noutput y = x[0]\nbasis x: energy nan\n", 1, "error")
    prog_case("basis_reduce_bogus", "input x : real[2]\noutput y = x[0]\nbasis y: reduce magic\n", 1,
              "expected 'interp' or 'galerkin'")
    prog_case("basis_reduce_interp_ineligible", "input x : real[2]\noutput y = x[0] * x[1]\nbasis y: reduce interp\n", 1,
              "eligible")
    prog_case("basis_reduce_interp_input", "input x : real[2]\noutput y = x[0] * x[1]\nbasis x: reduce interp\n", 1, "")
    prog_case("basis_unknown_key", "input x : real[2]\noutput y = x[0]\nbasis x: size 3\n", 1, "error")
    prog_case("basis_repeated", "input x : real[2]\noutput y = x[0]\nbasis x: cap 3\nbasis x: cap 4\n", "either", "")
    prog_case("inline_output", "input x : real[2]\noutput y = x[0]\ninline y\n", 1, "error")
    prog_case("inline_unknown", "input x : real[2]\noutput y = x[0]\ninline nosuch\n", 1, "nosuch")
    prog_case("extern_of_nothing", "dim N\ninput x : real[N]\nextern v[i:N] of nosuch\noutput y[i:N] = v[i]\n", 1, "nosuch")
    prog_case("extern_as_exponent", "dim N\ninput x : real[N]\nextern v[i:N] of x\noutput y[i:N] = x[i]^v[i]\n", 1, "error")
    prog_case("param_scalar_index", "param e : real\ninput x : real[2]\noutput y = x[0] * e[0]\n", 1, "error")
    prog_case("use_twice", "use geometry\nuse geometry\n" + head + "x[0]\n", "either", "")
    prog_case("use_empty", "use\n" + head + "x[0]\n", 1, "error")
    prog_case("json_check", head + "x[0] * x[1]\n", 0, "", args=("--json",))
    prog_case("dump_all", head + "x[0] * x[1]\n", 0, "", args=("-dpslb",))
    prog_case("dump_unknown_letter", head + "x[0]\n", 2, "", args=("-dz",))
    prog_case("std_is_file", "use geometry\n" + head + "x[0]\n", 1, "geometry", args=("--std=vec.npg",))
    index_cases()
    # sparse operators over index tables: -1, out of range, duplicate entries, against numpy
    sparse_cases()
    interp_cases()


def heat_K(nbr, kappa):
    N = len(kappa)
    K = np.diag(1 + np.sum(np.where(nbr >= 0, kappa[:, None], 0), axis=1))
    for i in range(N):
        for k in range(nbr.shape[1]):
            j = nbr[i, k]
            if 0 <= j < N:
                K[i, j] -= kappa[i]
    return K


def laplacian(tab, w, N):
    L = np.eye(N)
    for e in range(len(tab)):
        a, b = tab[e]
        v = np.zeros(N)
        if 0 <= a < N:
            v[a] += 1
        if 0 <= b < N:
            v[b] -= 1
        L += w[e] * np.outer(v, v)
    return L


def index_cases():
    """Index arithmetic on index variables: out of range is refused at the entry, valid forms equal numpy."""
    n = X.shape[1]
    rev = np.arange(n)[::-1]
    cases = [("plus_one", "x[i+1]", None, "index 5 is out of range"),
             ("minus_one", "x[i-1]", None, "index -1 is out of range"),
             ("twice", "x[2*i]", None, "index 6 is out of range"),
             ("negated", "x[-i]", None, "index -1 is out of range"),
             ("square", "x[i*i]", None, "index 9 is out of range"),
             ("sum_one_past", "sum(k = 0..N, x[k])", None, "index 5 is out of range"),
             ("division", "x[(i+1)/2]", None, "an index must be an integer expression"),
             ("reversed", "x[N-1-i]", lambda x: x[:, rev], ""),
             ("guarded_shift", "if(i > 0, x[i-1], 0)", lambda x: np.concatenate([np.zeros((len(x), 1)), x[:, :-1]], 1), ""),
             ("guarded_both_ends", "if(i > 0, if(i < N-1, x[i-1] + x[i+1], 0), 0)",
              lambda x: np.concatenate([np.zeros((len(x), 1)), x[:, :-2] + x[:, 2:], np.zeros((len(x), 1))], 1), ""),
             ("suffix_sum", "sum(k = i..N-1, x[k])", lambda x: np.cumsum(x[:, ::-1], 1)[:, ::-1], ""),
             ("prefix_sum", "sum(k = 0..i, x[k])", lambda x: np.cumsum(x, 1), ""),
             ("empty_range_at_end", "sum(k = i+1..N-1, x[k])", lambda x: np.cumsum(x[:, ::-1], 1)[:, ::-1] - x, "")]
    for name, e, fn, msg in cases:
        write("ix/%s.npg" % name, "dim N\nparam rho : real[N]\ninput x : real[N]\noutput y[i:N] = %s\n" % e)
        argv = ["npgc", "eval", "ix/%s.npg" % name, "--full", "D", "D", "-o", "out/ix_" + name]
        if fn is None:
            case("index_" + name, argv, 1, msg)
        else:
            case("index_" + name, argv, "either" if name == "empty_range_at_end" else 0, "",
                 check=out_equals("out/ix_%s/y.npy" % name, fn(X), 1e-13))


def sparse_cases():
    heat = open(os.path.join(SRC, "tests/programs/heat_neighbours.npg")).read()
    lap = open(os.path.join(SRC, "tests/programs/graph_laplacian_delta.npg")).read()
    write("sp/heat.npg", heat)
    write("sp/lap.npg", lap)
    N = 6
    src = 1 + RNG.random(N)
    kap = 0.2 + RNG.random((3, N))
    grid = np.array([[1, -1, -1, -1], [0, 2, -1, -1], [1, 3, -1, -1], [2, 4, -1, -1], [3, 5, -1, -1], [4, -1, -1, -1]])
    tables = {
        "chain": grid,
        "all_minus_one": -np.ones((N, 4), dtype=int),
        "duplicates": np.array([[1, 1, 1, -1], [0, 0, 2, 2], [1, 3, 3, 3], [2, 4, -1, -1], [3, 5, 5, 5], [4, 4, 4, 4]]),
        "self_loops": np.array([[0, 1, -1, -1], [1, 0, 2, -1], [2, 1, 3, -1], [3, 2, 4, -1], [4, 3, 5, -1], [5, 4, -1, -1]]),
        "out_of_range": np.where(grid == 5, 9, grid),
        "minus_two": np.where(grid == -1, -2, grid),
        "huge_entry": np.where(grid == 5, 2**40, grid),
    }
    for name, nbr in tables.items():
        d = data_dir("sp/heat_" + name, {"nbr": nbr.astype(np.int64), "src": src, "kappa": kap})
        want = np.array([np.linalg.solve(heat_K(nbr, k), src) for k in kap])
        case("sparse_heat_%s_eval" % name, ["npgc", "eval", "sp/heat.npg", "--full", d, d, "-o", "out/sp_heat_" + name],
             "either", "", check=out_equals("out/sp_heat_%s/u.npy" % name, want, 1e-9))
    nbr32 = data_dir("sp/heat_int32", {"nbr": grid.astype(np.int32), "src": src, "kappa": kap})
    want = np.array([np.linalg.solve(heat_K(grid, k), src) for k in kap])
    case("sparse_heat_int32_table_eval", ["npgc", "eval", "sp/heat.npg", "--full", nbr32, nbr32, "-o", "out/sp_h32"], 0, "",
         check=out_equals("out/sp_h32/u.npy", want, 1e-9))
    # a singular operator: kappa making a row zero is refused, not solved into garbage
    sing = data_dir("sp/heat_singular", {"nbr": grid, "src": src, "kappa": np.array([[-1.0 / 1] + [0.5] * (N - 1)])})
    ksing = np.array([[-1.0] + [0.5] * (N - 1)])
    case("sparse_heat_negative_kappa_eval", ["npgc", "eval", "sp/heat.npg", "--full", sing, sing, "-o", "out/sp_sing"],
         "either", "", check=out_equals("out/sp_sing/u.npy", np.array([np.linalg.solve(heat_K(grid, k), src)
                                                                       for k in ksing]), 1e-8))
    E = 7
    w = 0.1 + RNG.random((3, E))
    f = 1 + RNG.random(N)
    ltab = {
        "ring": np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [5, 0], [0, 3]]),
        "duplicate_edges": np.array([[0, 1], [0, 1], [0, 1], [3, 4], [4, 5], [5, 0], [2, 3]]),
        "self_edge": np.array([[0, 0], [1, 2], [2, 3], [3, 4], [4, 5], [5, 0], [1, 1]]),
        "minus_one": np.array([[0, -1], [1, 2], [-1, 3], [3, 4], [4, 5], [5, 0], [-1, -1]]),
        "out_of_range": np.array([[0, 6], [1, 2], [2, 3], [3, 4], [4, 5], [5, 0], [99, 1]]),
    }
    for name, tab in ltab.items():
        d = data_dir("sp/lap_" + name, {"tab": tab.astype(np.int64), "f": f, "w": w})
        want = np.array([np.linalg.solve(laplacian(tab, wk, N), f) for wk in w])
        case("sparse_lap_%s_eval" % name, ["npgc", "eval", "sp/lap.npg", "--full", d, d, "-o", "out/sp_lap_" + name],
             "either", "", check=out_equals("out/sp_lap_%s/y.npy" % name, want, 1e-9))
    # an indefinite negative weight: still a solve (LU), equal to numpy
    d = data_dir("sp/lap_negative_w", {"tab": ltab["ring"], "f": f, "w": -w * 0.1})
    want = np.array([np.linalg.solve(laplacian(ltab["ring"], -wk * 0.1, N), f) for wk in w])
    case("sparse_lap_negative_weights_eval", ["npgc", "eval", "sp/lap.npg", "--full", d, d, "-o", "out/sp_lapneg"],
         "either", "", check=out_equals("out/sp_lapneg/y.npy", want, 1e-9))
    # an unguarded gather through a padded table in an op
    write("sp/gather_op.npg", "dim N\nparam nbr : int[N, 2]\nparam f : real[N]\ninput k : real[N]\n"
          "op A[i:N, j:N] = delta(i, j) * (3 + k[nbr[i, 0]] * k[nbr[i, 1]])\noutput u = solve(A, f)\n")
    gt = np.array([[1, 2], [0, -1], [1, 3], [2, 4], [3, 5], [4, 0]])
    d = data_dir("sp/gather_pad", {"nbr": gt, "f": f, "k": 1 + RNG.random((2, N))})
    case("sparse_unguarded_gather_minus_one", ["npgc", "eval", "sp/gather_op.npg", "--full", d, d, "-o", "out/sp_g"], 1,
         "nbr")
    # training and verify of a sparse program on tables with duplicates
    d = data_dir("sp/lap_train", {"tab": ltab["duplicate_edges"], "f": f, "w": 0.1 + RNG.random((16, E))})
    case("sparse_lap_duplicates_train", ["npgc", "train", "sp/lap.npg", d, "-o", "models/sp_lap"], 0, "",
         check=lambda p: None if os.path.exists(path("models/sp_lap/manifest")) else "no model")


def interp_cases():
    nb = open(os.path.join(SRC, "tests/programs/nbody_gravity.npg")).read()
    write("ip/nbody.npg", nb)
    write("ip/nbody_interp.npg", nb + "basis w: reduce interp\n")
    write("ip/nbody_galerkin.npg", nb + "basis w: reduce galerkin\n")
    write("ip/nbody_interp_a.npg", nb + "basis a: reduce interp\n")
    write("ip/nbody_interp_twice.npg", nb + "basis w: reduce interp\nbasis w: reduce galerkin\n")
    base = RNG.normal(size=(6, 3)) * 2
    modes = RNG.normal(size=(3, 6, 3))
    S = 24
    x = base + np.einsum("sk,kvc->svc", 0.2 * RNG.normal(size=(S, 3)), modes)
    d = data_dir("ip/D", {"x": x, "mass": np.full(6, 1 / 6), "eps": np.array(0.05)})
    case("interp_stmt_check", ["npgc", "check", "ip/nbody_interp.npg"], 0, "", stream="out")
    case("interp_stmt_train", ["npgc", "train", "ip/nbody_interp.npg", d, "-o", "models/ip"], 0, "",
         check=lambda p: None if open(path("models/ip/manifest")).readline().strip() == "npg-model 2"
         else "the statement 'basis w: reduce interp' did not give an interpolated model")
    case("interp_stmt_ineligible", ["npgc", "check", "ip/nbody_interp_a.npg"], 1, "a")
    case("interp_stmt_conflicting", ["npgc", "check", "ip/nbody_interp_twice.npg"], "either", "")
    case("interp_stmt_vs_option", ["npgc", "train", "ip/nbody_interp.npg", d, "-o", "models/ip2", "--reduce",
                                   "w:galerkin"], "either", "")
    case("interp_oversample_zero", ["npgc", "train", "ip/nbody.npg", d, "-o", "models/ip3", "--reduce", "w:interp",
                                    "--interp-oversample", "0"], 2, "--interp-oversample")
    case("interp_oversample_nan", ["npgc", "train", "ip/nbody.npg", d, "-o", "models/ip3", "--reduce", "w:interp",
                                   "--interp-oversample", "nan"], 2, "--interp-oversample")
    case("interp_oversample_huge", ["npgc", "train", "ip/nbody.npg", d, "-o", "models/ip4", "--reduce", "w:interp",
                                    "--interp-oversample", "1e9"], "either", "")
    case("interp_reduce_unknown_stage", ["npgc", "train", "ip/nbody.npg", d, "-o", "models/ip5", "--reduce", "q:interp"],
         None, "q")
    case("interp_reduce_bad_kind", ["npgc", "train", "ip/nbody.npg", d, "-o", "models/ip5", "--reduce", "w:magic"],
         None, "magic")
    case("interp_reduce_twice", ["npgc", "train", "ip/nbody.npg", d, "-o", "models/ip6", "--reduce", "w:interp",
                                 "--reduce", "w:galerkin"], None, "w")
    case("interp_valid_fraction_zero", ["npgc", "train", "ip/nbody.npg", d, "-o", "models/ip7", "--valid", "0"], None,
         "0")
    case("interp_valid_fraction_big", ["npgc", "train", "ip/nbody.npg", d, "-o", "models/ip7", "--valid", "0.9"], None,
         "--valid")
    case("interp_valid_is_training", ["npgc", "train", "ip/nbody.npg", d, "-o", "models/ip8", "--valid", d], "either", "")


# ------------------------------------------------------------------ sealed forgeries of an interpolated (format 2) model


def manifest_lines(d):
    with open(path(d, "manifest"), "rb") as f:
        return f.read().split(b"\n")[:-1]


def seal(d, ls):
    """`ls` as d/manifest with the checksum a forger who knows the format computes."""
    body = b"".join(l + b"\n" for l in ls if not l.startswith(b"manifest "))
    with open(path(d, "manifest"), "wb") as f:
        f.write(body + b"manifest fnv1a64 %016x\n" % fnv1a64(body))


def reseal_array(d, name, a):
    blob = npy_bytes_of(a)
    write(os.path.join(d, name), blob)
    shape = b"x".join(b"%d" % n for n in a.shape)
    seal(d, [b"array %s %s fnv1a64 %016x" % (name.encode(), shape, fnv1a64(blob))
             if l.startswith(b"array " + name.encode() + b" ") else l for l in manifest_lines(d)])


def forge_cases():
    """The interpolated stage's arrays and manifest line, changed and resealed: refused naming the file,
    or (where the entry is unused padding) the same output as the genuine model."""
    write("ip/nbody.npg", open(os.path.join(SRC, "tests/programs/nbody_gravity.npg")).read())
    base = RNG.normal(size=(6, 3)) * 2
    modes = RNG.normal(size=(3, 6, 3))
    x = base + np.einsum("sk,kvc->svc", 0.2 * RNG.normal(size=(30, 3)), modes)
    data_dir("fg/D", {"x": x, "mass": np.full(6, 1 / 6), "eps": np.array(0.05)})
    npgc_ok("train", "ip/nbody.npg", "fg/D", "-o", "fg/MI", "--reduce", "w:interp")
    npgc_ok("eval", "ip/nbody.npg", "fg/MI", "fg/D", "-o", "fg/GOOD")
    good = np.load(path("fg/GOOD/a.npy"))

    def arr(name, mod):
        def f(d):
            a = np.load(path(d, name))
            mod(a)
            reseal_array(d, name, a)
        return f

    def setv(i, v):
        return lambda a: a.flat.__setitem__(i, v)

    def line(new):
        return lambda d: seal(d, [new if l.startswith(b"interp w") else l for l in manifest_lines(d)])
    forgeries = {
        "rows_huge": arr("interp_w_rows.npy", setv(0, 1e6)), "rows_negative": arr("interp_w_rows.npy", setv(3, -1)),
        "rows_fraction": arr("interp_w_rows.npy", setv(3, 0.5)), "rows_nan": arr("interp_w_rows.npy", setv(3, np.nan)),
        "rows_duplicate": arr("interp_w_rows.npy", lambda a: a.__setitem__(1, a[0])),
        "reads_huge": arr("interp_w_reads.npy", setv(5, 1e9)), "reads_negative": arr("interp_w_reads.npy", setv(5, -3)),
        "monos_huge": arr("interp_w_monos.npy", setv(0, 1e9)), "monos_padding_negative": arr("interp_w_monos.npy", setv(7, -2)),
        "monos_padding_nan": arr("interp_w_monos.npy", setv(7, np.nan)),
        "monos_used_negative": arr("interp_w_monos.npy", setv(2, -5)),
        "monos_used_fraction": arr("interp_w_monos.npy", setv(2, 2.5)),
        "pinv_inf": arr("interp_w_pinv.npy", setv(7, np.inf)),
        "pinv_transposed": lambda d: reseal_array(d, "interp_w_pinv.npy", np.load(path(d, "interp_w_pinv.npy")).T.copy()),
        "rows_shorter": lambda d: reseal_array(d, "interp_w_rows.npy", np.load(path(d, "interp_w_rows.npy"))[:-1].copy()),
        "line_k_huge": line(b"interp w k 99999 m 9 reads 36 monos 72 norm 1"),
        "line_m_zero": line(b"interp w k 36 m 0 reads 36 monos 72 norm 1"),
        "line_reads_huge": line(b"interp w k 36 m 9 reads 9999 monos 72 norm 1"),
        "line_monos_negative": line(b"interp w k 36 m 9 reads 36 monos -72 norm 1"),
        "line_norm_nan": line(b"interp w k 36 m 9 reads 36 monos 72 norm nan"),
        "line_other_stage": line(b"interp a k 36 m 9 reads 36 monos 72 norm 1"),
        "line_removed": lambda d: seal(d, [l for l in manifest_lines(d) if not l.startswith(b"interp w")]),
        "line_twice": lambda d: seal(d, manifest_lines(d)[:-1] + [l for l in manifest_lines(d) if l.startswith(b"interp w")]),
        "choice_garbage": lambda d: seal(d, [b"choice w magic 0 interp nan reason 99" if l.startswith(b"choice") else l
                                             for l in manifest_lines(d)]),
        "format_1": lambda d: seal(d, [b"npg-model 1" if l.startswith(b"npg-model") else l for l in manifest_lines(d)]),
        "format_4": lambda d: seal(d, [b"npg-model 4" if l.startswith(b"npg-model") else l for l in manifest_lines(d)]),
    }
    for name, fn in forgeries.items():
        d = "fg/F_" + name
        shutil.copytree(path("fg/MI"), path(d))
        fn(d)
        case("forge_%s_eval" % name, ["npgc", "eval", "ip/nbody.npg", d, "fg/D", "-o", "out/fg_" + name], "either", d,
             check=out_equals("out/fg_%s/a.npy" % name, good, 0))
        case("forge_%s_verify" % name, ["npgc", "verify", "ip/nbody.npg", d, "fg/D", "--tol", "1"], "either", d)


# ------------------------------------------------------------------ 3. .npy files not in corpus.py

def npy_header(descr="'<f8'", fortran="False", shape="(12, 5)"):
    return "{'descr': %s, 'fortran_order': %s, 'shape': %s, }" % (descr, fortran, shape)


def npy_bytes(header, data=b"", version=(1, 0), hraw=False):
    h = header.encode("latin-1") if isinstance(header, str) else header
    if not hraw:
        import struct
        prefix = 6 + 2 + (2 if version[0] == 1 else 4)
        total = prefix + len(h) + 1
        h = h + b" " * ((64 - total % 64) % 64) + b"\n"
    import struct
    lenfield = struct.pack("<H", len(h)) if version[0] == 1 else struct.pack("<I", len(h))
    return b"\x93NUMPY" + bytes(version) + lenfield + h + data


XB = X.astype("<f8").tobytes()


def npy_cases():
    """Each file replaces D/x.npy; the valid ones must give numpy's y, the others a message naming the file."""
    good, badf = {}, {}
    good["v2"] = npy_bytes(npy_header(), XB, version=(2, 0))
    good["v3_utf8"] = npy_bytes(npy_header(), XB, version=(3, 0))
    good["shape_spaces"] = npy_bytes(npy_header(shape="( 12 ,  5 )"), XB)
    good["shape_trailing_comma"] = npy_bytes(npy_header(shape="(12, 5,)"), XB)
    good["keys_reordered"] = npy_bytes("{'shape': (12, 5), 'fortran_order': False, 'descr': '<f8'}", XB)
    good["double_quotes"] = npy_bytes('{"descr": "<f8", "fortran_order": False, "shape": (12, 5)}', XB)
    good["no_trailing_comma"] = npy_bytes("{'descr': '<f8', 'fortran_order': False, 'shape': (12, 5)}", XB)
    good["tab_whitespace"] = npy_bytes("{'descr':\t'<f8',\t'fortran_order':\tFalse,\t'shape':\t(12,\t5)}", XB)
    good["fortran_one_column"] = npy_bytes(npy_header(fortran="True", shape="(12, 1)"), X[:, :1].tobytes())
    good["numpy_saved_view"] = X[:, ::-1].copy()[:, ::-1]
    good["negative_zero"] = np.where(X > 1.5, X, -0.0)
    good["denormals"] = np.where(X > 1.5, X, 5e-324)
    good["tiny"] = X * 1e-150
    good["equal_samples"] = np.tile(X[:1], (12, 1))
    badf["descr_native"] = (npy_bytes(npy_header(descr="'=f8'"), XB), "")
    badf["descr_no_order"] = (npy_bytes(npy_header(descr="'f8'"), XB), "")
    badf["descr_d"] = (npy_bytes(npy_header(descr="'<d'"), XB), "")
    badf["descr_f16"] = (npy_bytes(npy_header(descr="'<f16'"), XB + XB), "dtype")
    badf["descr_f2"] = (X.astype("<f2"), "dtype")
    badf["descr_datetime"] = (npy_bytes(npy_header(descr="'<M8[s]'"), XB), "dtype")
    badf["descr_empty"] = (npy_bytes(npy_header(descr="''"), XB), "dtype")
    badf["descr_unicode"] = (npy_bytes(npy_header(descr="'<f8\u00e9'").encode("utf-8"), XB, version=(3, 0)), "dtype")
    badf["fortran_none"] = (npy_bytes(npy_header(fortran="None"), XB), "fortran_order")
    badf["fortran_int"] = (npy_bytes(npy_header(fortran="0"), XB), "fortran_order")
    badf["fortran_2d"] = (npy_bytes(npy_header(fortran="True"), np.asfortranarray(X).tobytes(order="F")), "Fortran")
    badf["shape_none"] = (npy_bytes(npy_header(shape="None"), XB), "shape")
    badf["shape_plus"] = (npy_bytes(npy_header(shape="(+12, 5)"), XB), "")
    badf["shape_hex"] = (npy_bytes(npy_header(shape="(0xc, 5)"), XB), "")
    badf["shape_underscore"] = (npy_bytes(npy_header(shape="(1_2, 5)"), XB), "")
    badf["shape_leading_zero"] = (npy_bytes(npy_header(shape="(012, 5)"), XB), "")
    badf["shape_bool"] = (npy_bytes(npy_header(shape="(True, 5)"), XB), "shape")
    badf["shape_nested"] = (npy_bytes(npy_header(shape="((12, 5))"), XB), "shape")
    badf["shape_empty_entry"] = (npy_bytes(npy_header(shape="(12, , 5)"), XB), "")
    badf["shape_swapped"] = (X.T.copy(), "shape")
    badf["shape_3d_same_count"] = (X.reshape(12, 5, 1), "shape")
    badf["shape_6x10"] = (X.reshape(6, 10), "")
    badf["header_cr"] = (npy_bytes(npy_header().replace(", ", ",\r"), XB), "")
    badf["header_nl_inside"] = (npy_bytes(npy_header().replace(", ", ",\n"), XB), "")
    badf["header_v1_utf8"] = (npy_bytes(npy_header(descr="'<f8'").replace("descr", "d\u00e9scr").encode("utf-8"), XB),
                              "")
    badf["header_v2_huge_len"] = (b"\x93NUMPY\x02\x00" + (0x7FFFFFFF).to_bytes(4, "little") + b"{", "")
    badf["header_only_brace"] = (npy_bytes("{}", XB), "")
    badf["header_key_unquoted"] = (npy_bytes("{descr: '<f8', fortran_order: False, shape: (12, 5)}", XB), "")
    badf["header_comment"] = (npy_bytes(npy_header() + " # hi", XB), "")
    badf["nan_payload_signalling"] = (np.where(np.arange(60).reshape(12, 5) == 3,
                                               np.frombuffer(b"\x01\x00\x00\x00\x00\x00\xf0\x7f", dtype="<f8")[0], X),
                                      "NaN")
    badf["huge_values"] = (X * 1e300, "")
    badf["overflowing_square"] = (np.where(np.arange(60).reshape(12, 5) == 7, 1.5e154, X), "")
    badf["max_double"] = (np.where(np.arange(60).reshape(12, 5) == 9, 1.7976931348623157e308, X), "")
    for name, blob in good.items():
        d = "npy/g_" + name
        shutil.copytree(path("D"), path(d))
        write(d + "/x.npy", blob if isinstance(blob, bytes) else npy_bytes_of(blob))
        xv = np.load(path(d, "x.npy"))
        want = vec_y(xv.reshape(len(xv), -1)) if xv.shape[-1] == 5 else None
        if name == "fortran_one_column":
            case("npy_good_%s_eval" % name, ["npgc", "eval", "vec.npg", "--full", d, d, "-o", "out/g_" + name],
                 None, "")
            continue
        case("npy_good_%s_eval" % name, ["npgc", "eval", "vec.npg", "--full", d, d, "-o", "out/g_" + name], 0, "",
             check=out_equals("out/g_%s/y.npy" % name, want, 1e-14))
        case("npy_good_%s_reduced" % name, ["npgc", "eval", "vec.npg", "M", d, "-o", "out/gr_" + name],
             "either" if name in ("tiny", "denormals") else 0, "",
             check=out_equals("out/gr_%s/y.npy" % name, want, 5e-2))
    for name, (blob, msg) in badf.items():
        d = "npy/b_" + name
        shutil.copytree(path("D"), path(d))
        write(d + "/x.npy", blob if isinstance(blob, bytes) else npy_bytes_of(blob))
        try:
            xv = np.load(path(d, "x.npy"))
            want = vec_y(xv) if xv.shape == (12, 5) and xv.dtype == np.float64 else None
        except Exception:
            # numpy refuses the header; npg may read it as the X it holds (a lenient but right reading)
            want = vec_y(X) if name.startswith("shape_") and len(blob) == len(npy_bytes_of(X)) else None
        st = "either" if want is not None else 1
        chk = out_equals("out/b_%s/y.npy" % name, want, 1e-14) if want is not None else None
        case("npy_bad_%s_eval" % name, ["npgc", "eval", "vec.npg", "--full", d, d, "-o", "out/b_" + name], st,
             msg if st == 1 else "", check=chk)
        case("npy_bad_%s_train" % name, ["npgc", "train", "vec.npg", d, "-o", "models/b_" + name], "either", "",
             check=None)
        case("npy_bad_%s_verify" % name, ["npgc", "verify", "vec.npg", "M", d], None if want is None else "either", "")


def npy_bytes_of(a):
    import io
    b = io.BytesIO()
    np.save(b, a)
    return b.getvalue()


# ------------------------------------------------------------------ 4. numeric extremes in training and verify

def numeric_cases():
    def train(name, arrays, extra=(), status=0, msg="", prog="vec.npg"):
        d = data_dir("num/" + name, arrays)
        case("num_%s_train" % name, ["npgc", "train", prog, d, "-o", "models/num_" + name] + list(extra), status, msg)
        return d
    train("one_sample", {"rho": RHO, "x": X[:1]}, status="either")
    train("two_samples", {"rho": RHO, "x": X[:2]})
    train("constant_samples", {"rho": RHO, "x": np.tile(X[:1], (12, 1))})
    train("zero_samples_all_zero", {"rho": RHO, "x": np.zeros((12, 5))}, status="either")
    train("rank_one", {"rho": RHO, "x": np.outer(1 + np.arange(12.0), X[0])})
    train("scale_1e150", {"rho": RHO, "x": X * 1e150}, status="either")
    train("scale_1e-150", {"rho": RHO, "x": X * 1e-150}, status="either")
    train("mixed_scales", {"rho": RHO, "x": X * np.array([1e-100, 1, 1e100, 1, 1])}, status="either")
    train("rho_zero", {"rho": np.zeros(5), "x": X})
    train("rho_negative", {"rho": -RHO, "x": X})
    train("rho_denormal", {"rho": np.full(5, 5e-324), "x": X})
    train("cap_one", {"rho": RHO, "x": X}, ["--cap", "1"])
    train("energy_tiny", {"rho": RHO, "x": X}, ["--energy", "1e-300"])
    train("energy_one", {"rho": RHO, "x": X}, ["--energy", "1"])
    train("center_off", {"rho": RHO, "x": X}, ["--center", "off"])
    train("merge_joint", {"rho": RHO, "x": X}, ["--merge", "joint"])
    train("mem_tiny", {"rho": RHO, "x": X}, ["--mem", "1"], status="either")
    train("mem_1k", {"rho": RHO, "x": X}, ["--mem", "1k"], status="either")
    train("fewer_samples_than_dim", {"rho": 1 + RNG.random(40), "x": 1 + RNG.random((3, 40))})
    # out of core (--mem small) and --cc: the model the in-memory, libtcc training makes, to rounding
    rng = np.random.default_rng(5)
    data_dir("num/big", {"rho": 1 + rng.random(40), "x": 1 + rng.random((200, 40))})
    npgc_ok("train", "vec.npg", "num/big", "-o", "num/big_ref")
    npgc_ok("eval", "vec.npg", "num/big_ref", "num/big", "-o", "num/big_ref_out")
    ref = np.load(path("num/big_ref_out/y.npy"))
    for tag, extra in (("mem_1k", ["--mem", "1k"]), ("mem_20k", ["--mem", "20k"]), ("mem_100k", ["--mem", "100k"]),
                       ("cc", ["--cc"]), ("progress", ["--progress"])):
        m = "models/big_" + tag

        def check(p, m=m, tag=tag):
            e = subprocess.run([NPGC, "eval", "vec.npg", m, "num/big", "-o", "out/big_" + tag], cwd=W,
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            if e.returncode:
                return "eval: " + e.stderr.decode()[:200]
            return close(np.load(path("out/big_%s/y.npy" % tag)), ref, 1e-10, 0, "y of the model trained with " + tag)
        case("num_same_model_" + tag, ["npgc", "train", "vec.npg", "num/big", "-o", m] + extra, 0, "", check=check)
    # verify/eval results against numpy on models trained at extreme scales
    for name, scale in (("1e100", 1e100), ("1e-100", 1e-100), ("1", 1.0)):
        d = data_dir("num/sc_" + name, {"rho": RHO, "x": X * scale})
        t = data_dir("num/sct_" + name, {"rho": RHO, "x": X[:4] * scale})
        m = "models/sc_" + name

        def before(d=d, m=m):
            if not os.path.exists(path(m, "manifest")):
                subprocess.run([NPGC, "train", "vec.npg", d, "-o", m], cwd=W, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
        want = vec_y(X[:4] * scale)
        case("num_scale_%s_eval_reduced" % name, ["npgc", "eval", "vec.npg", m, t, "-o", "out/sc_" + name], "either", "",
             check=out_equals("out/sc_%s/y.npy" % name, want, 1e-3), before=before)
    # a singular dense solve and an indefinite root
    write("num/solve.npg", open(os.path.join(SRC, "tests/programs/solve_stage.npg")).read())
    F = 4
    a = RNG.random((F, F))
    x = 1 + RNG.random((3, F))
    e = 1 + RNG.random((3, F))
    rho = np.full(F, 0.1)
    d = data_dir("num/solve_ok", {"rho": rho, "a": a, "x": x, "e": e})
    want = []
    for k in range(3):
        p = a * np.outer(x[k], x[k])
        want.append(np.linalg.solve(np.eye(F) - rho[:, None] * p, e[k]))
    case("num_solve_dense_eval", ["npgc", "eval", "num/solve.npg", "--full", d, d, "-o", "out/num_solve"], 0, "",
         check=out_equals("out/num_solve/b.npy", np.array(want), 1e-9))
    # rho making M = I - rho p singular exactly: p = 1 everywhere, rho = 1/F rows... use F=1 analog via all-ones
    d = data_dir("num/solve_singular", {"rho": np.ones(F), "a": np.eye(F), "x": np.ones((2, F)), "e": e[:2]})
    case("num_solve_singular_eval", ["npgc", "eval", "num/solve.npg", "--full", d, d, "-o", "out/num_sing"], 1, "")
    write("num/root.npg", open(os.path.join(SRC, "tests/programs/root_of_op.npg")).read())
    d = data_dir("num/root_indef", {"a": -3 * np.eye(F), "x": x})
    case("num_root_indefinite_eval", ["npgc", "eval", "num/root.npg", "--full", d, d, "-o", "out/num_root"], 1, "")
    aa = RNG.random((F, F)) * 0.1
    d = data_dir("num/root_ok", {"a": aa, "x": x})
    Mx = aa + aa.T + np.eye(F)
    wv, V = np.linalg.eigh(Mx)
    R = V @ np.diag(np.sqrt(wv)) @ V.T
    case("num_root_spd_eval", ["npgc", "eval", "num/root.npg", "--full", d, d, "-o", "out/num_rootok"], 0, "",
         check=out_equals("out/num_rootok/y.npy", np.array([R @ xk for xk in x]), 1e-8))
    d = data_dir("num/root_semidef", {"a": np.full((F, F), -0.5) + 0.5 * np.eye(F) - 0.5 * np.eye(F) * 0, "x": x})
    case("num_root_semidefinite_eval", ["npgc", "eval", "num/root.npg", "--full", d, d, "-o", "out/num_rootsemi"],
         "either", "")
    # verify with extreme tolerances
    case("num_verify_tol_zero", ["npgc", "verify", "vec.npg", "M", "T", "--tol", "0"], "either", "")
    case("num_verify_tol_inf", ["npgc", "verify", "vec.npg", "M", "T", "--tol", "inf"], "either", "")
    case("num_verify_tol_denormal", ["npgc", "verify", "vec.npg", "M", "T", "--tol", "5e-324"], "either", "")
    case("num_verify_tol_1e300", ["npgc", "verify", "vec.npg", "M", "T", "--tol", "1e300"], 0, "")
    case("num_verify_exact_size_one", ["npgc", "verify", "vec.npg", "--exact", "--exact-size", "1"], 0, "")
    case("num_verify_exact_size_64", ["npgc", "verify", "vec.npg", "--exact", "--exact-size", "64"], 0, "")
    case("num_verify_test_one_sample", ["npgc", "verify", "vec.npg", "M", data_dir("num/t1", {"rho": RHO, "x": XT[:1]})],
         0, "")
    case("num_bench_one_sample", ["npgc", "bench", "vec.npg", "M", "num/t1", "--reps", "1"], 0, "")
    case("num_bench_reps_max", ["npgc", "bench", "vec.npg", "M", "num/t1", "--reps", "1000001"], 2, "--reps")


def honesty_cases():
    """verify's reported mean relative L2 error of an output equals the one computed here from the
    reduced eval's lifted output and numpy's exact value (a verify that flatters is a quiet wrong answer);
    and the reduced output is that close to numpy."""
    def honest(name, prog, train_dir, test_dir, out, want, extra=()):
        m = "models/hon_" + name

        def before(m=m):
            subprocess.run([NPGC, "train", prog, train_dir, "-o", m] + list(extra), cwd=W,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

        def check(p, m=m):
            e = subprocess.run([NPGC, "eval", prog, m, test_dir, "-o", "out/hon_" + name], cwd=W,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
            if e.returncode != 0:
                return "eval failed: " + e.stderr.decode()[:200]
            got = np.load(path("out/hon_%s/%s.npy" % (name, out)))
            g, w = got.reshape(len(got), -1), want.reshape(len(want), -1)
            mine = float(np.mean(np.linalg.norm(g - w, axis=1) / np.linalg.norm(w, axis=1)))
            rows = [l.split() for l in p.stdout.decode().splitlines() if l.split()[:1] == [out]]
            if not rows:
                return "verify printed no row for %s" % out
            said = float(rows[0][3])
            if abs(said - mine) > 1e-6 + 0.02 * mine:
                return "verify says L2 error %.4e for %s, the reduced eval's output is %.4e off numpy" % (said, out, mine)
            return None
        case("hon_" + name, ["npgc", "verify", prog, m, test_dir, "--tol", "1e9"], 0, "", check=check, stream="out",
             before=before)
    honest("vec_cap1", "vec.npg", "D", "T", "y", vec_y(XT), ["--cap", "1"])
    honest("vec_cap2_uncentered", "vec.npg", "D", "T", "y", vec_y(XT), ["--cap", "2", "--center", "off"])
    honest("vec_energy_half", "vec.npg", "D", "T", "y", vec_y(XT), ["--energy", "0.5"])
    honest("vec_joint", "vec.npg", "D", "T", "y", vec_y(XT), ["--merge", "joint", "--cap", "2"])
    honest("vec_full_rank", "vec.npg", "D", "T", "y", vec_y(XT))
    # the sparse heat operator: trained on 30 conductivities, tested on 5 others
    N = 6
    grid = np.array([[1, -1, -1, -1], [0, 2, -1, -1], [1, 3, -1, -1], [2, 4, -1, -1], [3, 5, -1, -1], [4, -1, -1, -1]])
    src = 1 + RNG.random(N)
    ktr, kte = 0.5 + RNG.random((30, N)), 0.5 + RNG.random((5, N))
    data_dir("hon/heat_tr", {"nbr": grid, "src": src, "kappa": ktr})
    data_dir("hon/heat_te", {"nbr": grid, "src": src, "kappa": kte})
    want = np.array([np.linalg.solve(heat_K(grid, k), src) for k in kte])
    honest("heat_cap3", "sp/heat.npg", "hon/heat_tr", "hon/heat_te", "u", want, ["--cap", "3"])
    honest("heat_full", "sp/heat.npg", "hon/heat_tr", "hon/heat_te", "u", want)
    # a dense solve stage and a root of an operator
    F = 4
    a = RNG.random((F, F)) * 0.3
    rho = np.full(F, 0.1)
    xs, es = 1 + RNG.random((30, F)), 1 + RNG.random((30, F))
    data_dir("hon/solve_tr", {"rho": rho, "a": a, "x": xs[:25], "e": es[:25]})
    data_dir("hon/solve_te", {"rho": rho, "a": a, "x": xs[25:], "e": es[25:]})
    want = np.array([np.linalg.solve(np.eye(F) - rho[:, None] * (a * np.outer(xk, xk)), ek)
                     for xk, ek in zip(xs[25:], es[25:])])
    honest("solve_cap2", "num/solve.npg", "hon/solve_tr", "hon/solve_te", "b", want, ["--cap", "2"])
    honest("solve_full", "num/solve.npg", "hon/solve_tr", "hon/solve_te", "b", want)
    aa = RNG.random((F, F)) * 0.1
    Mx = aa + aa.T + np.eye(F)
    wv, V = np.linalg.eigh(Mx)
    R = V @ np.diag(np.sqrt(wv)) @ V.T
    data_dir("hon/root_tr", {"a": aa, "x": xs[:25]})
    data_dir("hon/root_te", {"a": aa, "x": xs[25:]})
    honest("root_cap2", "num/root.npg", "hon/root_tr", "hon/root_te", "y", np.array([R @ xk for xk in xs[25:]]),
           ["--cap", "2"])
    # the n-body stage by interpolation and by Galerkin
    base = RNG.normal(size=(6, 3)) * 2
    modes = RNG.normal(size=(3, 6, 3))
    xb = base + np.einsum("sk,kvc->svc", 0.2 * RNG.normal(size=(36, 3)), modes)
    mass, eps = np.full(6, 1 / 6), 0.05
    data_dir("hon/nb_tr", {"x": xb[:30], "mass": mass, "eps": np.array(eps)})
    data_dir("hon/nb_te", {"x": xb[30:], "mass": mass, "eps": np.array(eps)})

    def accel(x):
        d = x[None, :, :] - x[:, None, :]
        r2 = np.sum(d * d, axis=2) + eps
        np.fill_diagonal(r2, 1)
        w = r2 ** -1.5
        return np.einsum("j,ijc,ij->ic", mass, d, w)
    want = np.array([accel(xk) for xk in xb[30:]])
    honest("nbody_galerkin", "ip/nbody.npg", "hon/nb_tr", "hon/nb_te", "a", want)
    honest("nbody_interp", "ip/nbody.npg", "hon/nb_tr", "hon/nb_te", "a", want, ["--reduce", "w:interp"])
    # the full evaluator of the same program against numpy
    case("hon_nbody_full_eval", ["npgc", "eval", "ip/nbody.npg", "--full", "hon/nb_te", "hon/nb_te", "-o", "out/nbf"], 0,
         "", check=out_equals("out/nbf/a.npy", want, 1e-10))


def output_folder_cases():
    """What an output folder already holds that the command does not write must survive."""
    os.makedirs(path("of/OUT"), exist_ok=True)
    write("of/OUT/notes.txt", "mine\n")
    case("of_eval_full_keeps_other_files", ["npgc", "eval", "vec.npg", "--full", "D", "D", "-o", "of/OUT"], 0, "",
         check=both(kept("of/OUT/notes.txt"), out_equals("of/OUT/y.npy", vec_y(X), 1e-14)))
    os.makedirs(path("of/OUT2/y.npy"), exist_ok=True)
    write("of/OUT2/y.npy/inner", "mine\n")
    case("of_eval_output_name_is_a_folder", ["npgc", "eval", "vec.npg", "--full", "D", "D", "-o", "of/OUT2"], 1,
         "of/OUT2/y.npy", check=kept("of/OUT2"))
    os.makedirs(path("of/OUT3"), exist_ok=True)
    write("of/OUT3/notes.txt", "mine\n")
    write("of/OUT3/y.reduced.npy", "old\n")
    case("of_eval_reduced_keeps_other_files", ["npgc", "eval", "vec.npg", "M", "T", "-o", "of/OUT3"], 0, "",
         check=both(kept("of/OUT3/notes.txt"), out_equals("of/OUT3/y.npy", vec_y(XT), 5e-2)))
    os.makedirs(path("of/SP"), exist_ok=True)
    write("of/SP/notes.txt", "mine\n")
    case("of_spectra_keeps_other_files", ["npgc", "train", "vec.npg", "D", "-o", "models/of_sp", "--spectra", "of/SP"],
         0, "", check=kept("of/SP/notes.txt"))
    os.makedirs(path("of/SP2/spectrum_y.npy"), exist_ok=True)
    keep_sp2 = kept("of/SP2")   # refused before training: DIR untouched and no model written
    case("of_spectra_name_is_a_folder", ["npgc", "train", "vec.npg", "D", "-o", "models/of_sp2", "--spectra", "of/SP2"],
         None, "of/SP2", check=lambda p: keep_sp2(p) or ("a model was written" if os.path.exists(path("models/of_sp2"))
                                                         else None))
    write("of/readonly.c", "int mine;\n", mode=0o444)
    case("of_emit_over_readonly_file", ["npgc", "emit", "vec.npg", "-o", "of/readonly.c"], "either", "",
         check=lambda p: None if os.stat(path("of/readonly.c")).st_mode & 0o777 in (0o444, 0o644) else
         "permissions changed to %o" % (os.stat(path("of/readonly.c")).st_mode & 0o777))
    os.makedirs(path("of/hl"), exist_ok=True)
    write("of/user.npy", npy_bytes_of(X))
    shutil.copytree(path("M"), path("of/MH"))
    name = sorted(f for f in os.listdir(path("of/MH")) if f.startswith("basis"))[0]
    os.remove(path("of/MH", name))
    os.link(path("of/user.npy"), path("of/MH", name))
    case("of_retrain_model_with_hardlink", ["npgc", "train", "vec.npg", "D", "-o", "of/MH", "--cap", "2"], "either", "",
         check=kept("of/user.npy"))


# ------------------------------------------------------------------ 5. command lines not in corpus.py / options.sh

def cli_cases():
    os.makedirs(path("npyp"), exist_ok=True)
    shutil.copytree(path("D"), path("npyp/D"))
    def cli(name, argv, status, msg="", check=None):
        case("cli_" + name, ["npgc"] + argv, status, msg, check=check)
    cli("cap_equals", ["train", "vec.npg", "D", "-o", "models/cli_eq", "--cap=3"], 0)
    cli("cap_equals_empty", ["train", "vec.npg", "D", "-o", "models/cli_x", "--cap="], 2, "--cap")
    cli("cap_plus", ["train", "vec.npg", "D", "-o", "models/cli_plus", "--cap", "+3"], "either")
    cli("cap_space", ["train", "vec.npg", "D", "-o", "models/cli_x", "--cap", " 3"], "either")
    cli("cap_trailing_space", ["train", "vec.npg", "D", "-o", "models/cli_x", "--cap", "3 "], 2, "--cap")
    cli("cap_float", ["train", "vec.npg", "D", "-o", "models/cli_x", "--cap", "3.0"], 2, "--cap")
    cli("cap_hex", ["train", "vec.npg", "D", "-o", "models/cli_x", "--cap", "0x3"], 2, "--cap")
    cli("cap_octal", ["train", "vec.npg", "D", "-o", "models/cli_oct", "--cap", "010"], "either")
    cli("cap_unicode_digit", ["train", "vec.npg", "D", "-o", "models/cli_x", "--cap", "\u0663"], 2, "--cap")
    cli("cap_repeated", ["train", "vec.npg", "D", "-o", "models/cli_rep", "--cap", "3", "--cap", "2"], "either")
    cli("o_repeated", ["train", "vec.npg", "D", "-o", "models/cli_o1", "-o", "models/cli_o2"], "either")
    cli("o_equals", ["train", "vec.npg", "D", "-o=models/cli_oeq"], "either")
    cli("energy_hex_float", ["train", "vec.npg", "D", "-o", "models/cli_x", "--energy", "0x1p-1"], "either")
    cli("energy_denormal", ["train", "vec.npg", "D", "-o", "models/cli_den", "--energy", "5e-324"], "either")
    cli("energy_minus_zero", ["train", "vec.npg", "D", "-o", "models/cli_x", "--energy", "-0"], 2, "--energy")
    cli("energy_infinity_word", ["train", "vec.npg", "D", "-o", "models/cli_x", "--energy", "infinity"], 2, "--energy")
    cli("energy_comma_decimal", ["train", "vec.npg", "D", "-o", "models/cli_x", "--energy", "0,9"], 2, "--energy")
    cli("mem_fraction", ["train", "vec.npg", "D", "-o", "models/cli_memf", "--mem", "1.5M"], "either")
    cli("mem_lower_k", ["train", "vec.npg", "D", "-o", "models/cli_memk", "--mem", "100k"], "either")
    cli("mem_overflow", ["train", "vec.npg", "D", "-o", "models/cli_x", "--mem", "99999999999T"], 2, "--mem")
    cli("center_yes", ["train", "vec.npg", "D", "-o", "models/cli_x", "--center", "yes"], 2, "--center")
    cli("center_equals_off", ["train", "vec.npg", "D", "-o", "models/cli_coff", "--center=off"], 0)
    cli("basis_star", ["train", "vec.npg", "D", "-o", "models/cli_star", "--basis", "*:cap=2"], 0)
    cli("basis_empty", ["train", "vec.npg", "D", "-o", "models/cli_x", "--basis", ""], 2, "--basis")
    cli("basis_colon_only", ["train", "vec.npg", "D", "-o", "models/cli_x", "--basis", "x:"], None, "--basis")
    cli("basis_two_keys_same", ["train", "vec.npg", "D", "-o", "models/cli_bb", "--basis", "x:cap=2,cap=3"], "either")
    cli("basis_center_bad", ["train", "vec.npg", "D", "-o", "models/cli_x", "--basis", "x:center=maybe"], 2, "center")
    cli("basis_space_form", ["train", "vec.npg", "D", "-o", "models/cli_bsp", "--basis", "x:cap 2"], "either")
    cli("double_dash", ["train", "--", "vec.npg", "D", "-o", "models/cli_dd"], "either")
    cli("single_dash_data", ["train", "vec.npg", "-", "-o", "models/cli_x"], None, "-")
    cli("empty_program_arg", ["train", "", "D", "-o", "models/cli_x"], None, "")
    cli("empty_data_arg", ["train", "vec.npg", "", "-o", "models/cli_x"], None, "")
    cli("empty_out_arg", ["train", "vec.npg", "D", "-o", ""], None, "empty")
    cli("option_before_command", ["--cap", "3", "train", "vec.npg", "D", "-o", "models/cli_x"], 2, "")
    cli("help_each", ["train", "--help"], 0)
    cli("help_with_args", ["eval", "vec.npg", "--help"], 0)
    cli("version", ["--version"], "either")
    cli("command_case", ["TRAIN", "vec.npg", "D", "-o", "models/cli_x"], 2, "TRAIN")
    cli("command_prefix", ["tra", "vec.npg", "D", "-o", "models/cli_x"], 2, "tra")
    cli("emit_std_missing_dir", ["emit", "vec.npg", "-o", "out/cli_emit.c", "--std=/nonexistent"], "either")
    cli("emit_reduced_other_prog", ["emit", "two.npg", "--reduced", "M", "-o", "out/cli_emit2.c"], 1, "program")
    cli("emit_to_dev_full", ["emit", "vec.npg", "-o", "/dev/full"], 1, "/dev/full")
    cli("emit_ok_compiles", ["emit", "vec.npg", "-o", "out/cli_emit_ok.c"], 0,
        check=lambda p: None if subprocess.run(["cc", "-c", "-o", os.devnull, path("out/cli_emit_ok.c"),
                                                "-I", os.path.join(SRC, "include")],
                                               stderr=subprocess.DEVNULL).returncode == 0
        else "the emitted C does not compile")
    cli("check_json_to_dev_full", ["check", "vec.npg", "--json"], "either")
    cli("eval_full_cc", ["eval", "vec.npg", "--full", "D", "D", "-o", "out/cli_cc", "--cc"], 0,
        check=out_equals("out/cli_cc/y.npy", vec_y(X), 1e-14))
    cli("eval_exact_roots_full", ["eval", "vec.npg", "--full", "D", "D", "-o", "out/x", "--exact-roots"], 2,
        "--exact-roots")
    cli("eval_full_and_model", ["eval", "vec.npg", "--full", "D", "M", "T", "-o", "out/x"], 2, "")
    cli("eval_out_is_model", ["eval", "vec.npg", "M", "T", "-o", "M"], 1, "M", check=kept("M"))
    cli("eval_out_is_test", ["eval", "vec.npg", "M", "T", "-o", "T"], 1, "T", check=kept("T"))
    cli("eval_out_trailing_slash_model", ["eval", "vec.npg", "M", "T", "-o", "M/"], 1, "M", check=kept("M"))
    cli("eval_out_dot", ["eval", "vec.npg", "--full", "D", "D", "-o", "."], "either", "", check=kept("vec.npg", "D"))
    cli("eval_out_parent_of_data", ["eval", "vec.npg", "--full", "npyp/D", "npyp/D", "-o", "npyp"], "either", "",
        check=kept("npyp/D"))
    cli("eval_model_via_dotdot", ["eval", "vec.npg", "./M/../M", "T", "-o", "out/cli_dotdot"], 0,
        check=out_equals("out/cli_dotdot/y.npy", vec_y(XT), 5e-2))
    cli("verify_params_option", ["verify", "vec.npg", "M", "T", "--params", "D"], 0)
    cli("verify_params_missing", ["verify", "vec.npg", "M", "T", "--params", "nosuch"], 1, "nosuch")
    cli("verify_exact_with_model", ["verify", "vec.npg", "M", "--exact"], "either", "")
    cli("bench_params_option", ["bench", "vec.npg", "M", "T", "--params=D", "--reps=1"], 0)
    cli("bench_reps_negative", ["bench", "vec.npg", "M", "T", "--reps", "-1"], 2, "--reps")
    cli("bench_reps_equals_empty", ["bench", "vec.npg", "M", "T", "--reps="], 2, "--reps")
    cli("plot_ok", ["plot", "M", "-o", "out/cli_plot.png"], 0,
        check=lambda p: None if open(path("out/cli_plot.png"), "rb").read(8) == b"\x89PNG\r\n\x1a\n" else "not a PNG")
    cli("plot_no_o", ["plot", "M"], 2, "-o")
    cli("plot_data_folder", ["plot", "D", "-o", "out/cli_plot2.png"], 1, "D")
    shutil.copytree(path("M"), path("Mp"))
    cli("plot_over_own_model", ["plot", "Mp", "-o", "Mp/basis_0.npy"], 1, "Mp", check=kept("Mp"))
    cli("plot_to_dev_full", ["plot", "M", "-o", "/dev/full"], 1, "/dev/full")
    cli("plot_to_directory", ["plot", "M", "-o", "out"], 1, "out")
    # a model whose spectra were removed or changed after training
    for tag, damage in (("npy_removed", lambda d: os.remove(path(d, "spectrum_x.npy"))),
                        ("csv_removed", lambda d: os.remove(path(d, "spectrum_x.csv"))),
                        ("npy_truncated", lambda d: os.truncate(path(d, "spectrum_x.npy"), 100)),
                        ("npy_nan", lambda d: np.save(path(d, "spectrum_y.npy"),
                                                      np.where(np.arange(len(np.load(path(d, "spectrum_y.npy")))) == 0,
                                                               np.nan, np.load(path(d, "spectrum_y.npy")))))):
        shutil.copytree(path("M"), path("plotm/" + tag))
        damage("plotm/" + tag)
        cli("plot_spectrum_" + tag, ["plot", "plotm/" + tag, "-o", "out/plot_%s.png" % tag], 1, "plotm/" + tag,
            check=lambda p, tag=tag: "a PNG was written" if os.path.exists(path("out/plot_%s.png" % tag)) else None)
    case("cli_tune_tol_unreachable", ["npgc", "tune", "vec.npg", "D", "T", "--tol", "1e-300", "-o", "models/cli_tu"], 1,
         "cannot be met", stream="out", check=lambda p: "a model was written" if os.path.exists(path("models/cli_tu")) else None)
    case("cli_tune_max_cap_one", ["npgc", "tune", "vec.npg", "D", "T", "--tol", "1e-3", "--max-cap", "1", "-o",
                                  "models/cli_tmc"], 1, "--max-cap", stream="out", check=lambda p: "a model was written" if os.path.exists(path("models/cli_tmc")) else None)
    cli("plot_two_models", ["plot", "M", "M", "-o", "out/cli_plot3.png"], 2, "")
    cli("tune_ok", ["tune", "vec.npg", "D", "T", "--tol", "0.01", "-o", "models/cli_tune"], "either")
    cli("tune_tol_zero", ["tune", "vec.npg", "D", "T", "--tol", "0", "-o", "models/cli_tune0"], None, "--tol")
    cli("tune_tol_nan", ["tune", "vec.npg", "D", "T", "--tol", "nan", "-o", "models/cli_tune1"], 2, "--tol")
    cli("tune_no_tol", ["tune", "vec.npg", "D", "T", "-o", "models/cli_tune2"], 2, "--tol")
    cli("tune_max_cap_zero", ["tune", "vec.npg", "D", "T", "--tol", "0.1", "--max-cap", "0", "-o", "models/cli_t3"], 2,
        "--max-cap")
    cli("tune_valid_is_data", ["tune", "vec.npg", "D", "D", "--tol", "0.1", "-o", "models/cli_t4"], "either")
    cli("tune_valid_missing", ["tune", "vec.npg", "D", "nosuch", "--tol", "0.1", "-o", "models/cli_t5"], 1, "nosuch")
    # refused before anything is written: no model folder left holding a PNG (nor a model with a PNG manifest)
    cli("tune_png_is_own_model", ["tune", "vec.npg", "D", "T", "--tol", "0.1", "-o", "models/cli_t6", "--png",
                                  "models/cli_t6/manifest"], 1, "--png", check=lambda p: None if not
        os.path.exists(path("models/cli_t6")) else "models/cli_t6 was left: %s" % os.listdir(path("models/cli_t6")))
    cli("tune_png_in_own_model_dotted", ["tune", "vec.npg", "D", "T", "--tol", "0.1", "-o", "models/cli_t7/", "--png",
                                         "./models//x/../cli_t7/sub/chart.png"], 1, "--png", check=lambda p: None if
        not os.path.exists(path("models/cli_t7")) else "models/cli_t7 was left")
    cli("tune_out_is_valid", ["tune", "vec.npg", "D", "T", "--tol", "0.1", "-o", "T"], 1, "T", check=kept("T"))
    cli("spectra_into_data", ["train", "vec.npg", "D", "-o", "models/cli_sp", "--spectra", "D"], "either", "",
        check=kept("D/x.npy", "D/rho.npy"))
    cli("spectra_is_file", ["train", "vec.npg", "D", "-o", "models/cli_sp2", "--spectra", "vec.npg"], 1, "",
        check=kept("vec.npg"))
    # OpenMPI keeps allocations of MPI_Init past MPI_Finalize: its suppressions, as tests/mpi/mpi.sh sets them
    case("cli_train_mpi_without_mpirun", ["npgc", "train", "vec.npg", "D", "-o", "models/cli_mpi", "--mpi"], "either",
         env=dict(os.environ, ASAN_OPTIONS=os.environ.get("ASAN_OPTIONS", "") + ":fast_unwind_on_malloc=0",
                  LSAN_OPTIONS="suppressions=" + os.path.join(SRC, "tests/mpi/lsan.supp"),
                  OMPI_MCA_mca_base_component_disable_dlclose="1"))
    cli("train_progress_not_tty", ["train", "vec.npg", "D", "-o", "models/cli_prog", "--progress"], 0)


# ------------------------------------------------------------------ 6. file system hostility

def fs_cases():
    # as root, permissions are checked by running as nobody; as another user they apply already
    nobody = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups"] if os.geteuid() == 0 else []
    # read-only places, as a user who is not root
    os.makedirs(path("ro"), exist_ok=True)
    shutil.copytree(path("D"), path("ro/D"))
    shutil.copytree(path("M"), path("ro/M"))
    for root, dirs, files in os.walk(path("ro")):
        for d in dirs:
            os.chmod(os.path.join(root, d), 0o555)
        for f in files:
            os.chmod(os.path.join(root, f), 0o444)
    os.chmod(path("ro"), 0o555)
    os.makedirs(path("rw"), exist_ok=True)
    os.chmod(path("rw"), 0o777)
    for f in ("vec.npg",):
        os.chmod(path(f), 0o644)
    case("fs_ro_train_into_ro_dir", nobody + [NPGC, "train", "vec.npg", "ro/D", "-o", "ro/M2"], 1, "ro/M2")
    case("fs_ro_retrain_ro_model", nobody + [NPGC, "train", "vec.npg", "ro/D", "-o", "ro/M"], 1, "ro/M",
         check=kept("ro/M"))
    case("fs_ro_eval_from_ro", nobody + [NPGC, "eval", "vec.npg", "ro/M", "ro/D", "-o", "rw/ev"], 0,
         check=out_equals("rw/ev/y.npy", vec_y(X), 5e-2))
    case("fs_ro_eval_into_ro", nobody + [NPGC, "eval", "vec.npg", "ro/M", "ro/D", "-o", "ro/out"], 1, "ro/out")
    case("fs_ro_emit_into_ro", nobody + [NPGC, "emit", "vec.npg", "-o", "ro/x.c"], 1, "ro/x.c")
    case("fs_ro_plot_into_ro", nobody + [NPGC, "plot", "ro/M", "-o", "ro/p.png"], 1, "ro/p.png")
    os.makedirs(path("noread"), exist_ok=True)
    np.save(path("noread/x.npy"), X)
    np.save(path("noread/rho.npy"), RHO)
    os.chmod(path("noread/x.npy"), 0o000)
    case("fs_unreadable_npy", nobody + [NPGC, "eval", "vec.npg", "--full", "noread", "noread", "-o", "rw/nr"], 1,
         "noread/x.npy")
    write("noread.npg", VEC, mode=0o000)
    case("fs_unreadable_program", nobody + [NPGC, "check", "noread.npg"], 1, "noread.npg")
    os.makedirs(path("nox/D"), exist_ok=True)
    np.save(path("nox/D/x.npy"), X)
    np.save(path("nox/D/rho.npy"), RHO)
    os.chmod(path("nox"), 0o600)
    case("fs_unsearchable_dir", nobody + [NPGC, "eval", "vec.npg", "--full", "nox/D", "nox/D", "-o", "rw/nx"], 1, "nox/D")
    # symlinks, FIFOs and odd names as outputs and inputs
    os.makedirs(path("lnk"), exist_ok=True)
    os.symlink(path("vec.npg"), path("lnk/prog_link.npg"))
    case("fs_program_via_symlink", ["npgc", "check", "lnk/prog_link.npg"], 0, stream="out")
    os.symlink(path("D"), path("lnk/data_link"))
    case("fs_data_via_symlink", ["npgc", "eval", "vec.npg", "--full", "lnk/data_link", "lnk/data_link", "-o",
                                 "out/fs_dl"], 0, check=out_equals("out/fs_dl/y.npy", vec_y(X), 1e-14))
    os.symlink(path("M"), path("lnk/model_link"))
    case("fs_model_via_symlink_eval", ["npgc", "eval", "vec.npg", "lnk/model_link", "T", "-o", "out/fs_ml"], 0,
         check=out_equals("out/fs_ml/y.npy", vec_y(XT), 5e-2))
    write("lnk/target.c", "int keep_me;\n")
    os.symlink(path("lnk/target.c"), path("lnk/out_link.c"))
    case("fs_emit_to_symlink", ["npgc", "emit", "vec.npg", "-o", "lnk/out_link.c"], 1, "lnk/out_link.c",
         check=kept("lnk/target.c"))
    os.mkfifo(path("lnk/fifo.c"))
    case("fs_emit_to_fifo", ["npgc", "emit", "vec.npg", "-o", "lnk/fifo.c"], 1, "lnk/fifo.c", timeout=20)
    os.mkfifo(path("lnk/fifo.png"))
    case("fs_plot_to_fifo", ["npgc", "plot", "M", "-o", "lnk/fifo.png"], 1, "lnk/fifo.png", timeout=20)
    os.makedirs(path("lnk/eo"), exist_ok=True)
    os.symlink(path("lnk/target.c"), path("lnk/eo/y.npy"))
    case("fs_eval_out_holds_symlink", ["npgc", "eval", "vec.npg", "--full", "D", "D", "-o", "lnk/eo"], "either", "",
         check=kept("lnk/target.c"))
    os.symlink("/nonexistent/dir", path("lnk/dangling_out"))
    case("fs_eval_out_dangling_link", ["npgc", "eval", "vec.npg", "--full", "D", "D", "-o", "lnk/dangling_out"], 1, "")
    # a FIFO as an input, with a writer: read like a file
    os.makedirs(path("fifo_in"), exist_ok=True)
    np.save(path("fifo_in/rho.npy"), RHO)
    os.mkfifo(path("fifo_in/x.npy"))
    blob = npy_bytes_of(X)

    def feed():
        import threading

        def w():
            try:
                fd = os.open(path("fifo_in/x.npy"), os.O_WRONLY)
                os.write(fd, blob)
                os.close(fd)
            except OSError:
                pass
        threading.Thread(target=w, daemon=True).start()
    case("fs_fifo_input_with_writer", ["npgc", "eval", "vec.npg", "--full", "fifo_in", "fifo_in", "-o", "out/fs_fifo"],
         "either", "", check=out_equals("out/fs_fifo/y.npy", vec_y(X), 1e-14), before=feed, timeout=30)
    # standard streams closed: a file opened later gets descriptor 1 or 2; nothing printed may land in it
    def model_verifies(m):
        def check(p):
            v = subprocess.run([NPGC, "verify", "vec.npg", m, "T"], cwd=W, stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE)
            return None if v.returncode == 0 else "the model does not verify: " + v.stderr.decode()[:200]
        return check
    case("fs_stdout_closed_train", ["sh", "-c", '"$0" train vec.npg D -o models/fs_so >&-', NPGC], "either", "",
         check=model_verifies("models/fs_so"))
    case("fs_stderr_closed_train", ["sh", "-c", '"$0" train vec.npg D -o models/fs_se 2>&- >/dev/null', NPGC], "either",
         "", check=model_verifies("models/fs_se"))
    case("fs_stdout_closed_eval", ["sh", "-c", '"$0" eval vec.npg --full D D -o out/fs_so >&-', NPGC], "either", "",
         check=out_equals("out/fs_so/y.npy", vec_y(X), 1e-14))
    case("fs_stdout_closed_emit", ["sh", "-c", '"$0" emit vec.npg -o out/fs_so.c >&-', NPGC], "either", "",
         check=lambda p: None if open(path("out/fs_so.c")).read(2) == "/*" else "the C file does not start as C")
    case("fs_stdout_closed_check_json", ["sh", "-c", '"$0" check vec.npg --json >&-', NPGC], 1, "standard output")
    case("fs_stdin_closed_train", ["sh", "-c", '"$0" train vec.npg D -o models/fs_si <&- >/dev/null', NPGC], 0, "",
         check=model_verifies("models/fs_si"))
    # names: spaces, newlines, unicode, very long
    for tag, name in (("space", "my data dir"), ("newline", "new\nline"), ("unicode", "d\u00e4t\u00e4 \u2603"),
                      ("dash", "-D"), ("quote", "it's \"q\""), ("percent", "%s%n%d"), ("backslash", "a\\b")):
        shutil.copytree(path("D"), path("names", name))
        case("fs_name_%s_train" % tag, ["npgc", "train", "vec.npg", "names/" + name, "-o", "names/" + name + " M"], 0)
        case("fs_name_%s_eval" % tag, ["npgc", "eval", "vec.npg", "--full", "names/" + name, "names/" + name, "-o",
                                       "names/" + name + " out"], 0,
             check=out_equals("names/%s out/y.npy" % name, vec_y(X), 1e-14))
        case("fs_name_%s_missing" % tag, ["npgc", "eval", "vec.npg", "--full", "names/" + name + "x",
                                          "names/" + name + "x", "-o", "out/nm"], 1, name)
    longdir = "long/" + "/".join(["d" * 200] * 25)
    case("fs_long_out_path", ["npgc", "train", "vec.npg", "D", "-o", longdir], 1, "")
    case("fs_long_component", ["npgc", "eval", "vec.npg", "--full", "D", "D", "-o", "out/" + "n" * 300], 1, "")
    case("fs_long_program_path", ["npgc", "check", "/".join(["p" * 250] * 20) + ".npg"], 1, "")
    # a full disk: a small tmpfs of our own
    mnt = path("tmpfs")
    os.makedirs(mnt, exist_ok=True)
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", mnt], stderr=subprocess.DEVNULL).returncode == 0
    if mounted:
        MOUNTS.append(mnt)
        big = np.save(path("D_big.npy"), 1 + RNG.random((400, 50)))
        data_dir("Dbig", {"rho": 1 + RNG.random(50), "x": np.load(path("D_big.npy"))})
        case("fs_full_disk_train", ["npgc", "train", "vec.npg", "Dbig", "-o", "tmpfs/M"], 1, "tmpfs/M",
             check=lambda p: None if not os.path.exists(path("tmpfs/M/manifest")) else "a model on a full disk")
        case("fs_full_disk_eval", ["npgc", "eval", "vec.npg", "--full", "Dbig", "Dbig", "-o", "tmpfs/E"], 1, "tmpfs/E")
        case("fs_full_disk_emit", ["npgc", "emit", "vec.npg", "-o", "tmpfs/big.c"], "either", "")
        case("fs_full_disk_plot", ["npgc", "plot", "M", "-o", "tmpfs/p.png"], "either", "")
    # an existing good model replaced by a training that fails: the old one stays
    shutil.copytree(path("M"), path("keep/M"))
    data_dir("keep/bad", {"rho": RHO, "x": np.where(np.arange(60).reshape(12, 5) == 11, np.nan, X)})
    case("fs_failed_retrain_keeps_model", ["npgc", "train", "vec.npg", "keep/bad", "-o", "keep/M"], 1, "NaN",
         check=kept("keep/M"))
    shutil.copytree(path("M"), path("keep/M2"))
    case("fs_retrain_other_program_keeps_on_error", ["npgc", "train", "two.npg", "keep/bad", "-o", "keep/M2"], 1, "",
         check=kept("keep/M2"))


MOUNTS = []


# ------------------------------------------------------------------ 7. concurrency and kills

def concurrency_cases():
    data_dir("cc/D", {"rho": 1 + RNG.random(30), "x": 1 + RNG.random((300, 30))})
    script = r'''
import os, subprocess, sys, time, random, signal
npgc, w, seed, mode = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
random.seed(seed)
out = os.path.join(w, "cc", "M_%d" % seed)
if mode == "kill":
    # a good model first, then a retraining killed at a random point: the model must load afterwards
    subprocess.run([npgc, "train", "vec.npg", "cc/D", "-o", out], cwd=w, check=True, stdout=subprocess.DEVNULL)
    p = subprocess.Popen([npgc, "train", "vec.npg", "cc/D", "-o", out, "--cap", "3"], cwd=w,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(random.random() * 0.6)
    p.send_signal(signal.SIGKILL)
    p.wait()
elif mode == "two":
    ps = [subprocess.Popen([npgc, "train", "vec.npg", "cc/D", "-o", out, "--cap", str(c)], cwd=w,
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE) for c in (2, 3)]
    errs = [p.communicate()[1].decode() for p in ps]
    if all(p.returncode != 0 for p in ps):
        print("both trainings failed: " + " | ".join(errs)); sys.exit(1)
elif mode == "eval_during_train":
    subprocess.run([npgc, "train", "vec.npg", "cc/D", "-o", out], cwd=w, check=True, stdout=subprocess.DEVNULL)
    p = subprocess.Popen([npgc, "train", "vec.npg", "cc/D", "-o", out, "--cap", "2"], cwd=w,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    for k in range(6):
        r = subprocess.run([npgc, "eval", "vec.npg", out, "cc/D", "-o", out + "_E%d" % k], cwd=w,
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        e = r.stderr.decode()
        if r.returncode < 0 or "Sanitizer" in e:
            print("eval crashed during a retraining: " + e[:300]); sys.exit(1)
        if r.returncode != 0 and "cannot open" not in e and "manifest" not in e:
            print("eval during a retraining failed unclearly: " + e[:300]); sys.exit(1)
    p.wait()
r = subprocess.run([npgc, "verify", "vec.npg", out, "cc/D", "--tol", "1"], cwd=w, stdout=subprocess.DEVNULL,
                   stderr=subprocess.PIPE)
if r.returncode != 0:
    print("the model does not verify afterwards: " + r.stderr.decode()[:300]); sys.exit(1)
left = [f for f in os.listdir(os.path.join(w, "cc")) if f.startswith("M_%d." % seed)]
print("OK leftovers=%s" % left)
'''
    write("cc/run.py", script)
    for k in range(12):
        case("conc_kill9_retrain_%02d" % k, [sys.executable, "cc/run.py", NPGC, W, str(100 + k), "kill"], 0, "OK",
             stream="out")
    for k in range(3):
        case("conc_two_trainings_%d" % k, [sys.executable, "cc/run.py", NPGC, W, str(200 + k), "two"], 0, "OK",
             stream="out")
    case("conc_eval_during_retrain", [sys.executable, "cc/run.py", NPGC, W, "300", "eval_during_train"], 0, "OK",
         stream="out")


# ------------------------------------------------------------------ 8. the C API

API_BIN = os.path.join(W, "trial2_api")


def api_cases():
    names = ["full_values", "full_param_changed_between_evals", "full_input_changed_in_place", "full_set_wrong_ndim",
             "full_set_wrong_size", "full_set_param_as_input", "full_set_input_as_param", "full_set_output",
             "full_set_negative_shape", "full_set_denormal", "full_set_huge_overflows", "full_get_before_eval",
             "full_get_unknown", "full_dim_unknown", "full_eval_after_unbind", "full_eval_negative_sample",
             "full_bind_params_missing_dir", "full_bind_params_then_set", "full_two_evaluators_one_program",
             "full_program_freed_first", "full_cc_backend_values",
             "npy_ndim_zero_roundtrip", "npy_ndim_nine", "npy_ndim_negative", "npy_zero_extent_roundtrip",
             "npy_write_into_missing_dir", "npy_write_over_directory", "npy_write_nan_roundtrip", "npy_read_missing",
             "npy_read_tiny_errbuf", "npy_read_zero_errbuf",
             "train_cap_int_max", "train_one_sample", "train_set_wrong_size", "train_set_param_name",
             "train_add_full_other_program", "train_add_full_smaller_program", "train_finish_twice", "train_add_after_finish", "train_finish_into_data_dir",
             "model_save_twice", "model_load_with_other_program", "model_dim_unknown", "model_class_out_of_range", "model_spectra_name_is_a_folder",
             "model_basis_negative_class", "reduced_set_wrong_count", "reduced_set_coords_too_many",
             "reduced_set_nan_coords", "reduced_lift_wrong_count", "reduced_lift_an_input", "reduced_two_on_one_model",
             "reduced_eval_repeat_same", "reduced_op_no_such", "reduced_coords_unknown", "reduced_coords_before_eval"]
    for n in names:
        case("api_" + n, [API_BIN, n, W], 0, "OK", stream="out")

    def rel_small(p):
        for line in p.stdout.decode().splitlines():
            if line.startswith("REL "):
                return None if float(line.split()[1]) < 0.05 else "reduced error %s in the training span" % line
        return "no REL line"
    case("api_reduced_accuracy_in_span", [API_BIN, "reduced_accuracy_in_span", W], 0, "OK", stream="out",
         check=rel_small)
    # the number parsers: a value must be the exact decimal value, or a refusal
    doubles = ["1e-400", "4.9e-324", "1e309", "-1e309", "0x10", " 5", "5 ", "+5", "-0", "nan", "NaN", "inf", "-inf",
               "1e", "1e+", ".", "-.5", "1.5e3", "1_0", "\u0663", "0.1e1", "1e-5", "00012", "1.7976931348623157e308",
               "2.2250738585072014e-308", "<empty>", "1,5", "5d", "0x1p3", "INF", "1e0000000000000000000001"]
    for s in doubles:
        case("api_parse_double_%s" % s.encode("unicode_escape").decode().replace(" ", "sp"),
             [API_BIN, "parse_double:" + s, W], 0, "", stream="out", check=parse_check(s, float))
    longs = ["9223372036854775807", "9223372036854775808", "-9223372036854775808", "4000000000000000001", "3.0", "1e3",
             "0x10", "010", "+7", "-0", " 7", "7 ", "<empty>", "\u0667", "12abc", "-", "+"]
    for s in longs:
        case("api_parse_long_%s" % s.encode("unicode_escape").decode().replace(" ", "sp"),
             [API_BIN, "parse_long:" + s, W], 0, "", stream="out", check=parse_check(s, int))


def parse_check(s, kind):
    """Accepted values must be what the decimal text says; refusals must say why."""
    def check(p):
        out = p.stdout.decode().strip()
        if out.startswith("REFUSED"):
            return None if len(out) > 10 else "refused without a message"
        if not out.startswith("VALUE "):
            return "no output"
        v = out.split(" ", 1)[1]
        txt = s.strip() if s != "<empty>" else ""
        try:
            if kind is float and txt.lower().lstrip("+-").startswith("0x"):
                want = float.fromhex(txt)   # C's hexadecimal notation: an exact value
            else:
                want = float(txt) if kind is float else int(txt, 10)
        except ValueError:
            return "accepted %r as %s" % (s, v)
        if kind is float:
            if math.isnan(want) or math.isinf(want):
                return "accepted %r (not a finite number) as %s" % (s, v)
            if float(v) != want and not (want == 0 and float(v) == 0):
                return "%r parsed as %s, not %r" % (s, v, want)
            if txt != s:
                return "accepted %r with surrounding spaces" % s
            if any(ch in s for ch in "_"):
                return "accepted %r" % s
        else:
            if int(v) != want:
                return "%r parsed as %s" % (s, v)
            if abs(want) > 4000000000000000000:
                return "%r accepted beyond the range" % s
            if txt != s:
                return "accepted %r with surrounding spaces" % s
        return None
    return check


# ------------------------------------------------------------------ 9. the Python module

PY_HEAD = r'''
import sys, os, gc, threading, numpy as np
import npg
W = sys.argv[1]
prog = npg.compile(os.path.join(W, "vec.npg"))
RHO = np.load(os.path.join(W, "D", "rho.npy"))
X = np.load(os.path.join(W, "D", "x.npy"))
def want(x, rho=RHO):
    return rho * x * x + x
def same(a, b, tol=1e-13):
    a = np.asarray(a); b = np.asarray(b)
    assert a.shape == b.shape, (a.shape, b.shape)
    assert np.max(np.abs(a - b)) <= tol * max(1, np.max(np.abs(b))), (a, b)
def refused(fn, *words, kinds=(npg.Error, TypeError, ValueError)):
    try:
        r = fn()
    except kinds as e:
        m = str(e)
        assert m, "an exception without a message"
        for w in words:
            assert w in m, "message %r lacks %r" % (m, w)
        return m
    raise AssertionError("accepted, returned %r" % (r,))
full = prog.full(params={"rho": RHO})
model = npg.load(prog, os.path.join(W, "M"))
'''

PY_CASES = {
    # dtypes and layouts
    "big_endian_input": "r = None\ntry:\n    r = full(x=X[0].astype('>f8'))['y']\nexcept (TypeError, npg.Error, ValueError) as e:\n"
                        "    assert str(e)\nif r is not None: same(r, want(X[0]))",
    "big_endian_param": "r = None\ntry:\n    f2 = prog.full(params={'rho': RHO.astype('>f8')}); r = f2(x=X[0])['y']\n"
                        "except (TypeError, npg.Error, ValueError) as e:\n    assert str(e)\nif r is not None: same(r, want(X[0]))",
    "big_endian_reduced": "red = model.reduced()\nr = None\ntry:\n    r = red(x=X[0].astype('>f8'))['y']\n"
                          "except (TypeError, npg.Error, ValueError) as e:\n    assert str(e)\n"
                          "if r is not None: same(r, model.reduced()(x=X[0])['y'])",
    "big_endian_trainer": "tr = npg.Trainer(full)\nok = True\ntry:\n    [tr.add(x=xk.astype('>f8')) for xk in X]\n"
                          "except (TypeError, npg.Error, ValueError) as e:\n    ok = False\nif ok:\n"
                          "    m = tr.finish(); red = m.reduced(); same(red.lift('y') if False else red(x=X[0]) and red.lift('y'), want(X[0]), 1e-6)",
    "negative_stride": "same(full(x=X[0][::-1].copy()[::-1])['y'], want(X[0]))\nsame(full(x=X[0, ::-1][::-1])['y'], want(X[0]))",
    "strided_column": "A = np.ascontiguousarray(X.T)\nsame(full(x=A[:, 3])['y'], want(X[3]))",
    "fortran_2d_param": "r = None\ntry:\n    r = prog.full(params={'rho': np.asfortranarray(RHO.reshape(5, 1))})\nexcept (TypeError, npg.Error, ValueError) as e:\n    assert str(e)",
    "readonly_input": "a = X[0].copy(); a.flags.writeable = False\nsame(full(x=a)['y'], want(X[0]))",
    "list_input": "r = None\ntry:\n    r = full(x=list(X[0]))['y']\nexcept (TypeError, npg.Error) as e:\n    assert str(e)\nif r is not None: same(r, want(X[0]))",
    "tuple_input": "r = None\ntry:\n    r = full(x=tuple(X[0]))['y']\nexcept (TypeError, npg.Error) as e:\n    assert str(e)\nif r is not None: same(r, want(X[0]))",
    "memoryview_input": "r = None\ntry:\n    r = full(x=memoryview(X[0].copy()))['y']\nexcept (TypeError, npg.Error) as e:\n    assert str(e)\nif r is not None: same(r, want(X[0]))",
    "bytes_input": "refused(lambda: full(x=X[0].tobytes()))",
    "string_input": "refused(lambda: full(x='12345'))",
    "none_input": "refused(lambda: full(x=None))",
    "scalar_input": "refused(lambda: full(x=1.0))",
    "zero_d_array": "refused(lambda: full(x=np.float64(2.0)))",
    "complex_input": "refused(lambda: full(x=X[0].astype(complex)))",
    "float16_input": "refused(lambda: full(x=X[0].astype(np.float16)))",
    "longdouble_input": "refused(lambda: full(x=X[0].astype(np.longdouble)))",
    "object_input": "refused(lambda: full(x=np.array(list(X[0]), dtype=object)))",
    "bool_input": "refused(lambda: full(x=np.ones(5, dtype=bool)))",
    "int_param": "r=None\ntry:\n    r = prog.full(params={'rho': np.array([1, 2, 3, 4, 5])})(x=X[0])['y']\nexcept (TypeError, npg.Error) as e:\n    assert str(e)\nif r is not None: same(r, want(X[0], np.arange(1., 6)))",
    "matrix_subclass": "r=None\ntry:\n    r = full(x=np.matrix(X[0]))['y']\nexcept (TypeError, npg.Error, ValueError) as e:\n    assert str(e)\nif r is not None: same(np.ravel(r), want(X[0]))",
    "masked_array": "r=None\nm = np.ma.masked_array(X[0], mask=[0, 1, 0, 0, 0])\ntry:\n    r = full(x=m)['y']\nexcept (TypeError, npg.Error, ValueError) as e:\n    assert str(e)\nif r is not None: same(r, want(X[0]))",
    "shape_2d_same_count": "refused(lambda: full(x=X[0].reshape(5, 1)))",
    "shape_empty": "refused(lambda: full(x=np.zeros(0)))",
    "huge_shape_broadcast": "refused(lambda: full(x=np.broadcast_to(1.0, (5,)).reshape(1, 5)))",
    "broadcast_view": "same(full(x=np.broadcast_to(1.5, (5,)))['y'], want(np.full(5, 1.5)))",
    "nan_param": "refused(lambda: prog.full(params={'rho': np.where(np.arange(5) == 2, np.nan, RHO)})(x=X[0]), 'rho')",
    "inf_input_reduced": "refused(lambda: model.reduced()(x=np.where(np.arange(5) == 1, np.inf, X[0])), 'x')",
    "denormal_input": "x = np.full(5, 5e-324)\nsame(full(x=x)['y'], want(x))",
    "huge_input_overflows": "refused(lambda: full(x=np.full(5, 1e300)), 'y')",
    # call orders and misuse
    "params_unknown_name": "refused(lambda: prog.full(params={'rho': RHO, 'sigma': RHO}), 'sigma')",
    "params_missing": "f = None\ntry:\n    f = prog.full(params={})\n    f(x=X[0])\n    raise AssertionError('evaluated without rho')\nexcept (npg.Error, TypeError, ValueError) as e:\n    assert 'rho' in str(e), str(e)",
    "params_not_dict": "refused(lambda: prog.full(params=[RHO]))",
    "params_dir_missing": "refused(lambda: prog.full(params=os.path.join(W, 'nosuch')), 'nosuch')",
    "params_bytes_path": "r=None\ntry:\n    r = prog.full(params=os.path.join(W, 'D').encode())(x=X[0])['y']\nexcept (TypeError, npg.Error) as e:\n    assert str(e)\nif r is not None: same(r, want(X[0]))",
    "params_pathlike": "import pathlib\nsame(prog.full(params=pathlib.Path(W) / 'D')(x=X[0])['y'], want(X[0]))",
    "compile_pathlike": "import pathlib\np2 = npg.compile(pathlib.Path(W) / 'vec.npg')\nsame(p2.full(params={'rho': RHO})(x=X[0])['y'], want(X[0]))",
    "compile_nul_in_path": "refused(lambda: npg.compile(os.path.join(W, 'vec.npg') + '\\0x'))",
    "compile_none": "refused(lambda: npg.compile(None))",
    "compile_int": "refused(lambda: npg.compile(3))",
    "compile_directory": "refused(lambda: npg.compile(W), 'directory')",
    "load_none_program": "refused(lambda: npg.load(None, os.path.join(W, 'M')))",
    "load_other_program": "p2 = npg.compile(os.path.join(W, 'two.npg'))\nrefused(lambda: npg.load(p2, os.path.join(W, 'M')), 'program')",
    "load_data_folder": "refused(lambda: npg.load(prog, os.path.join(W, 'D')), 'D')",
    "positional_args": "refused(lambda: full(X[0]))",
    "kwargs_twice_via_dict": "refused(lambda: full(**{'x': X[0], 'z': X[0]}), 'z')",
    "output_as_kwarg": "refused(lambda: full(x=X[0], y=X[0]), 'y')",
    "param_as_kwarg": "r=None\ntry:\n    r = full(x=X[0], rho=RHO)\nexcept (npg.Error, TypeError) as e:\n    assert 'rho' in str(e)",
    "full_get_before_eval": "f = prog.full(params={'rho': RHO})\ntry:\n    g = f.get('y')\n    assert g is None, g\nexcept (npg.Error, KeyError, ValueError) as e:\n    assert str(e)",
    "full_dim_unknown": "try:\n    d = full.dim('Q')\n    assert d is None or d < 0, d\nexcept (npg.Error, KeyError, ValueError) as e:\n    assert 'Q' in str(e)",
    "result_not_aliased": "a = full(x=X[0])['y']\nb = full(x=X[1])['y']\nsame(a, want(X[0]))\nsame(b, want(X[1]))",
    "result_writable_no_effect": "a = full(x=X[0])['y']\na[:] = 99\nsame(full(x=X[0])['y'], want(X[0]))",
    "input_mutated_after_call": "x = X[0].copy()\nr = full(x=x)['y']\nx[:] = 0\nsame(r, want(X[0]))",
    "reduced_lift_before_eval": "red = model.reduced()\nrefused(lambda: red.lift('y'))",
    "reduced_coords_before_eval": "red = model.reduced()\ntry:\n    c = red.coords('y')\n    assert c is None, c\nexcept (npg.Error, ValueError) as e:\n    assert str(e)",
    "reduced_set_coords_wrong_len": "red = model.reduced()\nrefused(lambda: red.set_coords('x', np.zeros(999)), 'x')",
    "reduced_set_coords_of_output": "red = model.reduced()\nrefused(lambda: red.set_coords('y', np.zeros(2)))",
    "reduced_lift_out_readonly": "red = model.reduced(); red(x=X[0])\nb = np.empty(5); b.flags.writeable = False\nrefused(lambda: red.lift('y', out=b))",
    "reduced_lift_out_strided": "red = model.reduced(); red(x=X[0])\nb = np.empty(10)[::2]\ntry:\n    r = red.lift('y', out=b)\n    same(b, red.lift('y'))\nexcept (TypeError, ValueError, npg.Error) as e:\n    assert str(e)",
    "reduced_lift_out_aliases_input": "red = model.reduced()\nx = X[0].copy(); red(x=x)\nr = red.lift('y', out=x)\nsame(x, model.reduced()(x=X[0]) and red.lift('y'))",
    "reduced_equals_cli": "import subprocess\nred = model.reduced()\nys = np.array([(red(x=xk), red.lift('y'))[1] for xk in X])\nsame(ys, want(X), 5e-2)",
    "model_outlives_program": "p2 = npg.compile(os.path.join(W, 'vec.npg'))\nm2 = npg.load(p2, os.path.join(W, 'M'))\ndel p2; gc.collect()\nred = m2.reduced(); red(x=X[0])\nsame(red.lift('y'), model.reduced()(x=X[0]) and model.reduced() and red.lift('y'))",
    "reduced_outlives_model": "m2 = npg.load(prog, os.path.join(W, 'M'))\nred = m2.reduced(); del m2; gc.collect()\nred(x=X[0]); r = red.lift('y')\nsame(r, want(X[0]), 5e-2)",
    "full_outlives_program": "p2 = npg.compile(os.path.join(W, 'vec.npg'))\nf2 = p2.full(params={'rho': RHO}); del p2; gc.collect()\nsame(f2(x=X[0])['y'], want(X[0]))",
    "trainer_outlives_full": "f2 = prog.full(params={'rho': RHO}); tr = npg.Trainer(f2); del f2; gc.collect()\nfor xk in X: tr.add(x=xk)\nm = tr.finish(); red = m.reduced(); red(x=X[0])\nsame(red.lift('y'), want(X[0]), 5e-2)",
    "trainer_finish_twice": "tr = npg.Trainer(full)\nfor xk in X: tr.add(x=xk)\nm = tr.finish()\ntry:\n    m2 = tr.finish()\n    r1, r2 = m.reduced(), m2.reduced(); r1(x=X[0]); r2(x=X[0])\n    assert np.array_equal(r1.lift('y'), r2.lift('y')), 'a second finish gave another model'\nexcept npg.Error as e:\n    assert str(e)",
    "trainer_add_after_finish": "tr = npg.Trainer(full)\nfor xk in X: tr.add(x=xk)\ntr.finish()\ntry:\n    tr.add(x=X[0] * 1.01)\n    assert tr.finish().samples == 13\nexcept npg.Error as e:\n    assert str(e)",
    "trainer_no_samples": "tr = npg.Trainer(full)\nrefused(lambda: tr.finish(), 'sample')",
    "trainer_one_sample": "tr = npg.Trainer(full)\ntr.add(x=X[0])\ntry:\n    m = tr.finish(); red = m.reduced(); red(x=X[0]); same(red.lift('y'), want(X[0]), 1e-8)\nexcept npg.Error as e:\n    assert str(e)",
    "trainer_cap_bool": "try:\n    npg.Trainer(full, cap=True)\nexcept (TypeError, ValueError) as e:\n    assert 'cap' in str(e)",
    "trainer_cap_huge": "refused(lambda: npg.Trainer(full, cap=10**30), 'cap', kinds=(ValueError, OverflowError, TypeError, npg.Error))",
    "trainer_cap_negative": "refused(lambda: npg.Trainer(full, cap=-1), 'cap')",
    "trainer_energy_nan": "refused(lambda: npg.Trainer(full, energy=float('nan')), 'energy')",
    "trainer_mem_zero": "refused(lambda: npg.Trainer(full, mem=0), 'mem')",
    "trainer_unknown_kwarg": "refused(lambda: npg.Trainer(full, caps=3))",
    "trainer_basis_not_dict": "refused(lambda: npg.Trainer(full, basis=[('x', 3)]))",
    "trainer_finish_into_data": "tr = npg.Trainer(full)\nfor xk in X: tr.add(x=xk)\nrefused(lambda: tr.finish(os.path.join(W, 'D')), 'D')\nassert os.path.exists(os.path.join(W, 'D', 'x.npy'))",
    "verify_wrong_test_type": "refused(lambda: model.verify(test=X, full=full))",
    "verify_zero_samples": "refused(lambda: model.verify(test={'x': X[:0]}, full=full))",
    "verify_tol_negative": "refused(lambda: model.verify(test={'x': X}, full=full, tol=-1), 'tol')",
    "verify_nan_test": "refused(lambda: model.verify(test={'x': np.where(X > 1.9, np.nan, X)}, full=full))",
    "verify_result_matches_numpy": "tr = npg.Trainer(full, cap=1)\nfor xk in X: tr.add(x=xk)\nm = tr.finish()\nrows = m.verify(test={'x': X}, tol=10)\nred = m.reduced()\nerr = np.mean([np.linalg.norm((red(x=xk), red.lift('y'))[1] - want(xk)) / np.linalg.norm(want(xk)) for xk in X])\nassert abs(rows['y']['l2'] - err) <= 1e-6 + 1e-3 * err, (rows['y']['l2'], err)",
    # threads and cycles
    "threads_share_full": "errs = []\ndef work(k):\n    try:\n        for i in range(30): same(full(x=X[k % 12])['y'], want(X[k % 12]))\n    except Exception as e: errs.append(repr(e))\nts = [threading.Thread(target=work, args=(k,)) for k in range(4)]\n[t.start() for t in ts]; [t.join() for t in ts]\nassert not errs or all('busy' in e or 'thread' in e for e in errs), errs[:2]",
    "threads_share_reduced": "red = model.reduced()\nerrs = []\ndef work(k):\n    try:\n        for i in range(30):\n            red(x=X[k]); r = red.lift('y')\n            if not np.all(np.isfinite(r)): errs.append('nonfinite')\n    except Exception as e: errs.append(repr(e))\nts = [threading.Thread(target=work, args=(k,)) for k in range(4)]\n[t.start() for t in ts]; [t.join() for t in ts]\nassert not [e for e in errs if 'busy' not in e and 'thread' not in e], errs[:2]",
    "threads_own_reduced": "errs = []\ndef work(k):\n    red = model.reduced()\n    try:\n        for i in range(30):\n            red(x=X[k]); r = red.lift('y')\n            same(r, want(X[k]), 5e-2)\n    except Exception as e: errs.append(repr(e))\nts = [threading.Thread(target=work, args=(k,)) for k in range(4)]\n[t.start() for t in ts]; [t.join() for t in ts]\nassert not errs, errs[:2]",
    "threads_train_two": "errs = []\ndef work(k):\n    try:\n        f = prog.full(params={'rho': RHO}); tr = npg.Trainer(f)\n        for xk in X: tr.add(x=xk)\n        tr.finish()\n    except Exception as e: errs.append(repr(e))\nts = [threading.Thread(target=work, args=(k,)) for k in range(2)]\n[t.start() for t in ts]; [t.join() for t in ts]\nassert not errs, errs",
    "cycle_extern_callable": "p2 = npg.compile(os.path.join(W, 'ext.npg'))\nf = p2.full()\nf.extern('v', lambda g, k, f=f: np.ones(5))\nsame(f(x=X[0])['y'], X[0])\ndel f; gc.collect()",
    "extern_returns_nan": "p2 = npg.compile(os.path.join(W, 'ext.npg'))\nf = p2.full()\nf.extern('v', lambda g, k: np.full(5, np.nan))\nrefused(lambda: f(x=X[0]), 'v')",
    "extern_returns_list": "p2 = npg.compile(os.path.join(W, 'ext.npg'))\nf = p2.full()\nf.extern('v', lambda g, k: [2.0] * 5)\ntry:\n    same(f(x=X[0])['y'], 2 * X[0])\nexcept (TypeError, npg.Error) as e:\n    assert str(e)",
    "extern_returns_int_array": "p2 = npg.compile(os.path.join(W, 'ext.npg'))\nf = p2.full()\nf.extern('v', lambda g, k: np.full(5, 2))\ntry:\n    same(f(x=X[0])['y'], 2 * X[0])\nexcept (TypeError, npg.Error) as e:\n    assert str(e)",
    "extern_returns_big_endian": "p2 = npg.compile(os.path.join(W, 'ext.npg'))\nf = p2.full()\nf.extern('v', lambda g, k: np.full(5, 2.0).astype('>f8'))\ntry:\n    same(f(x=X[0])['y'], 2 * X[0])\nexcept (TypeError, npg.Error) as e:\n    assert str(e)",
    "extern_returns_strided_view": "p2 = npg.compile(os.path.join(W, 'ext.npg'))\nf = p2.full()\nbuf = np.arange(10.0) + 1\nf.extern('v', lambda g, k: buf[::2])\ntry:\n    same(f(x=X[0])['y'], buf[::2] * X[0])\nexcept (TypeError, npg.Error) as e:\n    assert str(e)",
    "extern_returns_2d_same_count": "p2 = npg.compile(os.path.join(W, 'ext.npg'))\nf = p2.full()\nf.extern('v', lambda g, k: np.ones((5, 1)))\ntry:\n    same(f(x=X[0])['y'], X[0])\nexcept (TypeError, npg.Error) as e:\n    assert str(e)",
    "extern_returns_none": "p2 = npg.compile(os.path.join(W, 'ext.npg'))\nf = p2.full()\nf.extern('v', lambda g, k: None)\nrefused(lambda: f(x=X[0]))",
    "extern_unknown_name": "p2 = npg.compile(os.path.join(W, 'ext.npg'))\nf = p2.full()\nrefused(lambda: f.extern('nosuch', lambda g, k: np.ones(5)), 'nosuch')",
    "extern_replaced_midway": "p2 = npg.compile(os.path.join(W, 'ext.npg'))\nf = p2.full()\nf.extern('v', lambda g, k: np.ones(5))\nf(x=X[0])\nf.extern('v', lambda g, k: np.full(5, 3.0))\nsame(f(x=X[0])['y'], 3 * X[0])",
    "threads_share_trainer": "tr = npg.Trainer(full)\nerrs = []\ndef work(k):\n    try:\n        for i in range(20): tr.add(x=X[(k + i) % 12] * (1 + 0.01 * i))\n    except Exception as e: errs.append(repr(e))\nts = [threading.Thread(target=work, args=(k,)) for k in range(4)]\n[t.start() for t in ts]; [t.join() for t in ts]\nassert tr.samples + 0 == 80 - 20 * len(errs) or errs, (tr.samples, errs[:2])\nm = tr.finish(); red = m.reduced(); red(x=X[0]); same(red.lift('y'), want(X[0]), 5e-2)",
    "threads_full_and_trainer_add_full": "tr = npg.Trainer(full)\nerrs = []\ndef work(k):\n    try:\n        for i in range(20):\n            full(x=X[k]); tr.add_full()\n    except Exception as e: errs.append(repr(e))\nts = [threading.Thread(target=work, args=(k,)) for k in range(3)]\n[t.start() for t in ts]; [t.join() for t in ts]\nassert not [e for e in errs if 'busy' not in e and 'thread' not in e and 'evaluat' not in e], errs[:2]",
    "verify_with_other_program_full": "p2 = npg.compile(os.path.join(W, 'two.npg'))\nf2 = p2.full()\nrefused(lambda: model.verify(test={'x': X}, full=f2))",
    "set_coords_nan": "red = model.reduced()\nrefused(lambda: (red.set_coords('x', np.full(5, np.nan)), red())[1], 'x')",
    "set_coords_int_dtype": "red = model.reduced()\nrefused(lambda: red.set_coords('x', np.zeros(5, dtype=np.int64)))",
    "reduced_call_with_no_args": "red = model.reduced()\nrefused(lambda: red(), 'x')",
    "reduced_unknown_kwarg_and_good": "red = model.reduced()\nrefused(lambda: red(x=X[0], nosuch=X[0]), 'nosuch')",
    "full_many_kwargs_order": "a = full(x=X[0])['y']\nb = full(**{'x': X[0]})['y']\nassert np.array_equal(a, b)",
    "model_basis_sizes_match_manifest": "bs = model.basis_sizes\nassert set(bs) == {'{x}', '{y}'} and all(isinstance(v, int) and v >= 1 for v in bs.values()), bs",
    "load_twice_same_model": "m1 = npg.load(prog, os.path.join(W, 'M')); m2 = npg.load(prog, os.path.join(W, 'M'))\nr1, r2 = m1.reduced(), m2.reduced(); r1(x=X[3]); r2(x=X[3])\nassert np.array_equal(r1.lift('y'), r2.lift('y'))",
    "many_objects_gc": "for i in range(200):\n    f = prog.full(params={'rho': RHO}); f(x=X[i % 12]); r = model.reduced(); r(x=X[0])\ngc.collect()",
}


def python_cases():
    write("ext.npg", "dim N\ninput x : real[N]\nextern v[i:N] of x\noutput y[i:N] = v[i] * x[i]\n")
    env = dict(os.environ, PYTHONPATH=os.path.join(BUILD, "python"), PYTHONDONTWRITEBYTECODE="1")
    if SANITIZED:
        lib = subprocess.run(["cc", "-print-file-name=libasan.so"], stdout=subprocess.PIPE).stdout.decode().strip()
        env.update(LD_PRELOAD=lib, ASAN_OPTIONS="detect_leaks=0:abort_on_error=1",
                   UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1")
    if not os.path.isdir(os.path.join(BUILD, "python")):
        return
    for name, body in PY_CASES.items():
        write("py/%s.py" % name, PY_HEAD + body + "\nprint('OK')\n")
        case("py_" + name, ["/usr/bin/python3", path("py/%s.py" % name), W], 0, "OK", stream="out", env=env)


# ------------------------------------------------------------------ 10. the applications

def app_cases():
    apps = {a: os.path.join(BUILD, "npg-" + a) for a in ("radiosity", "fluids", "points")}
    if not all(os.path.exists(p) for p in apps.values()):
        return

    def app(name, a, args, status, msg="", check=None, timeout=None):
        case("app_" + name, [apps[a]] + args, status, msg, check=check, timeout=timeout)
    R, F, P = "radiosity", "fluids", "points"
    app("rad_no_command", R, [], 2, "usage")
    app("rad_unknown_command", R, ["render"], 2, "render")
    app("rad_faces_zero", R, ["scene", "--faces", "0"], 2, "--faces")
    app("rad_faces_negative", R, ["scene", "--faces", "-5"], 2, "--faces")
    app("rad_faces_huge", R, ["scene", "--faces", "99999999999"], 2, "--faces")
    app("rad_faces_float", R, ["scene", "--faces", "12.5"], 2, "--faces")
    app("rad_faces_repeated", R, ["scene", "--faces", "50", "--faces", "60", "--out", "out/rad_rep"], "either")
    app("rad_vis_samples_bad", R, ["full", "--out", "out/rad_x", "--vis-samples", "3"], 2, "--vis-samples")
    app("rad_vis_mode_bad", R, ["full", "--out", "out/rad_x", "--vis-mode", "laser"], 2, "--vis-mode")
    app("rad_solver_bad", R, ["full", "--out", "out/rad_x", "--solver", "magic"], 2, "--solver")
    app("rad_threads_zero", R, ["full", "--out", "out/rad_x", "--threads", "0"], "either")
    app("rad_threads_huge", R, ["full", "--out", "out/rad_x", "--threads", "100000"], 2, "--threads")
    app("rad_full_no_out", R, ["full"], 2, "--out")
    app("rad_run_missing_model", R, ["run", "--model", "nosuch"], 1, "nosuch")
    app("rad_run_model_other_prog", R, ["run", "--model", "M", "--frames", "2"], 1, "M")
    app("rad_train_energy_nan", R, ["train", "--out", "out/rad_x", "--energy", "nan"], 2, "--energy")
    app("rad_train_mem_zero", R, ["train", "--out", "out/rad_x", "--mem", "0"], 2, "--mem")
    app("rad_train_samples_one", R, ["train", "--out", "out/rad_s1", "--samples", "1", "--faces", "40"], "either",
        timeout=120)
    app("rad_ss_bad", R, ["demo", "--out", "out/rad_x", "--ss", "-1"], 2, "--ss")
    write("victim_rad.txt", "mine\n")
    app("rad_out_is_file", R, ["scene", "--out", "victim_rad.txt", "--faces", "40"], None, "victim_rad.txt",
        check=kept("victim_rad.txt"))
    # a model of a small scene run on the default scene: refused naming the sizes, not evaluated
    case("app_rad_demo_then_run_other_scene",
         ["sh", "-c", '"$0" demo --out out/rad_demo --faces 40 --samples 6 --frames 2 --reps 1 >/dev/null && '
          '"$0" run --model out/rad_demo/MODEL --frames 2', apps[R]], 1, "trained for", timeout=180)
    app("fl_no_command", F, [], 2, "usage")
    app("fl_cells_zero", F, ["mesh", "--cells", "0"], 2, "--cells")
    app("fl_size_negative", F, ["mesh", "--size", "-0.3"], 2, "--size")
    app("fl_size_huge", F, ["mesh", "--size", "5"], 2, "--size")
    app("fl_size_nan", F, ["mesh", "--size", "nan"], 2, "--size")
    app("fl_scale_zero", F, ["tunnel-full", "--out", "out/fl_x", "--scale", "0"], 2, "--scale")
    app("fl_pulse_huge", F, ["tunnel-full", "--out", "out/fl_x", "--pulse", "5"], 2, "--pulse")
    app("fl_period_zero", F, ["tunnel-full", "--out", "out/fl_x", "--period", "0"], 2, "--period")
    app("fl_u0_nan", F, ["tunnel-full", "--out", "out/fl_x", "--u0", "nan"], 2, "--u0")
    app("fl_u0_negative", F, ["tunnel-full", "--out", "out/fl_neg", "--u0", "-1", "--frames", "2", "--cells", "300",
                              "--particles", "10", "--png-every", "100", "--vtk-every", "100"], "either", timeout=120)
    app("fl_projection_bad", F, ["tunnel-full", "--out", "out/fl_x", "--projection", "al"], 2, "--projection")
    app("fl_png_every_zero", F, ["tunnel-full", "--out", "out/fl_x", "--png-every", "0"], 2, "--png-every")
    app("fl_particles_negative", F, ["tunnel-full", "--out", "out/fl_x", "--particles", "-1"], 2, "--particles")
    app("fl_sizes_empty", F, ["tunnel", "--out", "out/fl_x", "--sizes", ""], 2, "--sizes")
    app("fl_sizes_trailing_comma", F, ["tunnel", "--out", "out/fl_x", "--sizes", "8,", "--frames", "2", "--cells", "300",
                                       "--particles", "10", "--png-every", "100", "--vtk-every", "100"], 2, "--sizes")
    app("fl_sizes_descending", F, ["tunnel", "--out", "out/fl_x", "--sizes", "16,8", "--frames", "0"], 2, "")
    app("fl_keep_models_bad", F, ["tunnel", "--out", "out/fl_x", "--keep-models", "2"], 2, "--keep-models")
    app("fl_cavity_dt_zero", F, ["cavity", "--out", "out/fl_x", "--dt", "0"], 2, "--dt")
    app("fl_cavity_nu_negative", F, ["cavity", "--out", "out/fl_x", "--nu", "-1"], 2, "--nu")
    app("fl_cavity_backend_bad", F, ["cavity", "--out", "out/fl_x", "--backend", "gcc"], 2, "--backend")
    app("fl_cavity_workers_zero", F, ["cavity", "--out", "out/fl_x", "--workers", "0"], 2, "--workers")
    app("fl_cavity_projection_both", F, ["cavity", "--out", "out/fl_x", "--projection", "both"], 2, "--projection")
    app("fl_cavity_proj_method_bad", F, ["cavity-projection", "--method", "lu"], 2, "--method")
    write("victim_fl.txt", "mine\n")
    app("fl_out_is_file", F, ["tunnel-full", "--out", "victim_fl.txt", "--frames", "1", "--cells", "300"], None,
        "victim_fl.txt", check=kept("victim_fl.txt"))
    app("fl_tiny_run", F, ["tunnel-full", "--out", "out/fl_tiny", "--frames", "2", "--cells", "300", "--particles",
                           "10", "--png-every", "100", "--vtk-every", "100"], 0, timeout=120,
        check=lambda p: None if os.path.exists(path("out/fl_tiny/report.json")) else "no report")
    # more numbers out of their range, each bounded in size so that an accepted one ends quickly
    small_r = ["--faces", "40", "--frames", "2", "--samples", "6"]
    for tag, cmd, opt, val in (("rad_out_empty", "demo", "--out", ""), ("rad_frames_one", "full", "--frames", "1"),
                               ("rad_reps_zero", "demo", "--reps", "0"), ("rad_samples_zero", "train", "--samples", "0"),
                               ("rad_cap_zero", "train", "--cap", "0"), ("rad_energy_above_one", "train", "--energy", "1.5"),
                               ("rad_ss_zero", "demo", "--ss", "0"), ("rad_faces_equals_empty", "scene", "--faces=", None)):
        args = [cmd] + (["--out", "out/rad_" + tag] if opt != "--out" else []) + small_r
        args = [a for a in args if not (cmd == "scene" and a in ("--frames", "2", "--samples", "6"))]
        args += [opt] if val is None else [opt, val]
        if cmd in ("full", "scene"):
            args = [a for a in args if a not in ("--samples", "6")]
        app(tag, R, args, None, opt.rstrip("="), timeout=60)
    small_f = ["--cells", "300", "--frames", "2", "--particles", "10", "--png-every", "100", "--vtk-every", "100"]
    for tag, cmd, opt, val in (("fl_cells_text_equals", "mesh", "--cells=abc", None), ("fl_cells_exponent", "mesh", "--cells", "1e3"),
                               ("fl_runs_negative", "cavity", "--runs", "-1"), ("fl_mf_zero", "cavity", "--mf", "0"),
                               ("fl_dtol_nan", "cavity", "--dtol", "nan"), ("fl_buffer_negative", "cavity", "--buffer-mb", "-1"),
                               ("fl_sample_every_negative", "cavity", "--sample-every", "-1"),
                               ("fl_train_threads_zero", "cavity", "--train-threads", "0"),
                               ("fl_particle_threads_huge", "cavity", "--particle-threads", "99999"),
                               ("fl_steps_zero", "cavity-projection", "--steps", "0")):
        args = [cmd] + (["--out", "out/" + tag] if cmd in ("cavity",) else [])
        args += [opt] if val is None else [opt, val]
        if cmd == "cavity":
            args += ["--cells", "300", "--frames", "2"]
        app(tag, F, args, None, opt.split("=")[0], timeout=60)
    for tag, opt, val in (("pt_p_nine", "--p", "9"), ("pt_p_one", "--p", "1"), ("pt_leaf_negative", "--leaf", "-1"),
                          ("pt_check_points_negative", "--check-points", "-1"), ("pt_faces_tiny_rooms", "--faces", "3")):
        extra = ["--scene", "rooms"] if opt == "--faces" else []
        # --faces of the rooms is a target size (the scene has a smallest one): either refused or run
        app(tag, P, ["demo", "--out", "out/" + tag, "--points", "200", opt, val] + extra,
            "either" if opt == "--faces" else None, opt, timeout=60)
    app("pt_no_command", P, [], 2, "usage")
    app("pt_points_below_min", P, ["demo", "--out", "out/pt_x", "--points", "99"], 2, "--points")
    app("pt_leaf_zero", P, ["demo", "--out", "out/pt_x", "--points", "200", "--leaf", "0"], 2, "--leaf")
    app("pt_tol_zero", P, ["demo", "--out", "out/pt_x", "--points", "200", "--tol", "0"], 2, "--tol")
    app("pt_tol_nan", P, ["demo", "--out", "out/pt_x", "--points", "200", "--tol", "nan"], 2, "--tol")
    app("pt_scene_bad", P, ["demo", "--out", "out/pt_x", "--points", "200", "--scene", "cave"], 2, "--scene")
    app("pt_faces_negative", P, ["demo", "--out", "out/pt_x", "--points", "200", "--faces", "-3"], 2, "--faces")
    app("pt_no_out", P, ["demo", "--points", "200"], 2, "--out")
    app("pt_sweep_points_empty_entry", P, ["sweep", "--out", "out/pt_x", "--points", "200,,300", "--orders", "2",
                                               "--error-points", "200"], 2, "--points")
    app("pt_sweep_orders_zero", P, ["sweep", "--out", "out/pt_x", "--orders", "0"], 2, "--orders")
    write("victim_pt.txt", "mine\n")
    app("pt_out_is_file", P, ["demo", "--out", "victim_pt.txt", "--points", "200"], None, "victim_pt.txt",
        check=kept("victim_pt.txt"))
    app("pt_tiny_run", P, ["demo", "--out", "out/pt_tiny", "--points", "200", "--check-points", "0"], 0, timeout=120)


# ------------------------------------------------------------------ running

def run(c):
    argv = list(c["argv"])
    if argv[0] == "npgc":
        argv[0] = NPGC
    t0 = time.time()
    try:
        if c["before"]:
            c["before"]()
        p = subprocess.run(argv, cwd=c["cwd"], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, timeout=c["timeout"], env=c["env"])
    except subprocess.TimeoutExpired:
        return c["name"], "hangs: no exit within %d s" % c["timeout"], "", time.time() - t0
    err = p.stderr.decode("utf-8", "replace")
    out = p.stdout.decode("utf-8", "replace")
    text = out if c["stream"] == "out" else err
    first = (err.strip() or out.strip()).split("\n", 1)[0]
    status, msg = c["status"], c["msg"]
    problem = None
    if p.returncode < 0:
        problem = "killed by signal %d" % -p.returncode
    elif any(m in err for m in SANITIZER_MARKS):
        problem = "sanitizer report: " + next(l for l in err.splitlines() if any(m in l for m in SANITIZER_MARKS))[:160]
    elif status == "either":
        if p.returncode == 0:
            problem = c["check"](p) if c["check"] else None
        elif p.returncode == 1 or p.returncode == 2:
            if not err.strip() and not out.strip():
                problem = "refused with no message"
            elif msg and msg not in text:
                problem = "message lacks %r" % msg
        else:
            problem = "exit %d" % p.returncode
    else:
        if status is None:
            if p.returncode == 0:
                problem = "exit 0 on bad input"
            elif p.returncode > 2:
                problem = "exit %d" % p.returncode
        elif p.returncode == 0 and status != 0:
            problem = "exit 0 on bad input"
        elif p.returncode != status:
            problem = "exit %d, expected %d" % (p.returncode, status)
        if not problem:
            if msg.startswith("=") and text.split("\n", 1)[0] != msg[1:]:
                problem = "first line is not %r" % msg[1:]
            elif msg and not msg.startswith("=") and msg not in text:
                problem = "%s lacks %r" % ("stdout" if c["stream"] == "out" else "stderr", msg)
            elif p.returncode != 0 and not err.strip() and not out.strip():
                problem = "no message"
            elif c["check"]:
                problem = c["check"](p)
    if not problem and p.returncode == 0 and c["stream"] == "out" and "BAD" in out:
        problem = out.strip().splitlines()[-1][:200]
    return c["name"], problem, first[:200] + ("" if first else " [no output]"), time.time() - t0


def build_api():
    trialkit.build_api(SRC, BUILD, "tests/hostile/trial2_api.c", API_BIN)


def main():
    fixtures()
    build_api()
    expression_cases()
    front_end_cases()
    npy_cases()
    forge_cases()
    numeric_cases()
    honesty_cases()
    output_folder_cases()
    cli_cases()
    fs_cases()
    concurrency_cases()
    api_cases()
    python_cases()
    app_cases()
    names = [c["name"] for c in CASES]
    dup = {n for n in names if names.count(n) > 1}
    assert not dup, "case names used twice: %s" % sorted(dup)
    # (the Python and application cases exist only in builds that have them)
    made = {n.split("_")[0] for n in names}
    stale = {k for k in KNOWN_FAILURES if k not in names and k.split("_")[0] in made}
    assert not stale, "known failures that are not cases: %s" % sorted(stale)
    todo = [c for c in CASES if not ONLY or any(o in c["name"] for o in ONLY)]
    t0 = time.time()
    try:
        with ThreadPoolExecutor(max_workers=2) as pool:
            results = list(pool.map(run, todo))
    finally:
        for m in MOUNTS:
            subprocess.run(["umount", m], stderr=subprocess.DEVNULL)
    by_name = {c["name"]: c for c in CASES}
    failed, still_known, fixed = [], [], []
    for name, problem, first, secs in results:
        if VERBOSE:
            print("%-55s %5.1fs %s\n    %s" % (name, secs, problem or "ok", first))
        if name in KNOWN_FAILURES:
            (still_known if problem else fixed).append((name, problem))
        elif problem:
            failed.append((name, problem, first))
    kinds = {}
    for c in todo:
        kind = c["name"].split("_")[0]
        kinds[kind] = kinds.get(kind, 0) + 1
    print("hostile trial 2: %d cases in %.0f s (%s)" % (len(todo), time.time() - t0,
                                                       ", ".join("%s %d" % kv for kv in sorted(kinds.items()))))
    reasons = []
    for name, problem in still_known:
        if KNOWN_FAILURES[name] not in reasons:
            reasons.append(KNOWN_FAILURES[name])
        print("known failure %s: %s [%d]" % (name, problem, reasons.index(KNOWN_FAILURES[name]) + 1))
    for i, reason in enumerate(reasons):
        print("  [%d] %s" % (i + 1, reason))
    for name, _ in fixed:
        print("known failure %s now passes: move it out of KNOWN_FAILURES" % name)
    for name, problem, first in failed:
        c = by_name[name]
        print("FAIL %s: %s\n    %s\n    first line: %s" % (name, problem, " ".join(repr(a) if (" " in a or not a) else a
                                                                              for a in c["argv"]), first))
    print("%d of %d cases ended correctly (%d known failures)" % (len(todo) - len(failed) - len(still_known), len(todo),
                                                                len(still_known)))
    if failed:
        print("work folder kept: %s" % W)
        return 1
    shutil.rmtree(W, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
