#!/usr/bin/python3
"""corpus.py BUILD_DIR [NAME...] — the hostile-input corpus of npgc (issue 12).

Every case is one npgc command line on something a user or an attacker could
hand it: a malformed or lying .npy file, a damaged model, a pathological
program, a bad command line. Each carries its expectation: the exit status
and a substring of stderr (or, written "=...", its exact first line). A case
fails when npgc is killed by a signal, a sanitizer reports, it runs past the
timeout, it exits 0 on bad input, or its message is not the expected one.

The binary fixtures are made here, at test time, from the recipes below (the
Debian python3 and numpy): a small data set, a model trained from it by
npgc, and one damaged copy per case. Nothing binary is checked in.

KNOWN_FAILURES lists cases that still fail, each with its reason; they run
and are reported but do not fail the test (and say so once they pass).

With NAME arguments only the cases whose name contains one of them run;
NPG_CORPUS_VERBOSE=1 prints every case's stderr.
"""
import os
import shutil
import struct
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from trialkit import SANITIZER_MARKS, fnv1a64

BUILD = os.path.abspath(sys.argv[1])
NPGC = os.path.join(BUILD, "npgc")
ONLY = sys.argv[2:]
VERBOSE = os.environ.get("NPG_CORPUS_VERBOSE") == "1"
# sanitizer builds are several times slower; a hang is a minute or more anyway
TIMEOUT = 60

W = tempfile.mkdtemp(prefix="npg_corpus_")
CASES = []          # (name, argv, status, message)
KNOWN_FAILURES = {}  # name -> reason


def case(name, argv, status, message):
    CASES.append((name, argv, status, message))


def path(*parts):
    return os.path.join(W, *parts)


def write(rel, data, mode=0o644):
    p = path(rel)
    os.makedirs(os.path.dirname(p), exist_ok=True)
    with open(p, "wb" if isinstance(data, bytes) else "w") as f:
        f.write(data)
    os.chmod(p, mode)


# ------------------------------------------------------------------ programs

PROGRAMS = {
    # a param, an input, a contraction: the program most cases feed
    "vec.npg": "dim N\nparam rho : real[N]\ninput x : real[N]\noutput y[i:N] = rho[i] * x[i] * x[i] + x[i]\n",
    # the same program changed after training (another coefficient)
    "vec2.npg": "dim N\nparam rho : real[N]\ninput x : real[N]\noutput y[i:N] = rho[i] * x[i] * x[i] + 2 * x[i]\n",
    # two inputs, for sample counts that disagree across files
    "two.npg": "dim N\ninput x : real[N]\ninput z : real[N]\noutput y[i:N] = x[i] * z[i]\n",
    # an int param that gathers
    "gather.npg": "dim N, E\nparam e : int[E, 2]\ninput x : real[N]\noutput y[k:E] = x[e[k, 0]] * x[e[k, 1]]\n",
    # a root: a negative input is a NaN
    "root.npg": "dim N\ninput x : real[N]\noutput y[i:N] = x[i]^(1/2)\n",
    # a division: a zero input is an infinity
    "div.npg": "dim N\ninput x : real[N]\noutput y[i:N] = 1 / x[i]\n",
    # an extern, whose values come with the data
    "ext.npg": "dim N\ninput x : real[N]\nextern v[i:N] of x\noutput y[i:N] = v[i] * x[i]\n",
}


# ------------------------------------------------------------------ .npy bytes

def npy_header(descr="'<f8'", fortran="False", shape="(12, 5)", extra=""):
    return "{'descr': %s, 'fortran_order': %s, 'shape': %s, %s}" % (descr, fortran, shape, extra)


def npy_bytes(header, data=b"", magic=b"\x93NUMPY", version=(1, 0), hlen=None, pad=True):
    """A .npy file from its parts; `header` (text or bytes) is padded as numpy
    pads it unless `pad` is false, and `hlen` may lie about its length."""
    h = header.encode("latin-1") if isinstance(header, str) else header
    if pad:
        prefix = 6 + 2 + (2 if version[0] == 1 else 4)
        total = prefix + len(h) + 1
        h = h + b" " * ((64 - total % 64) % 64) + b"\n"
    n = len(h) if hlen is None else hlen
    lenfield = struct.pack("<H", n) if version[0] == 1 else struct.pack("<I", n)
    return magic + bytes(version) + lenfield + h + data


def npy_array(a):
    """numpy.save's bytes of `a`."""
    import io
    b = io.BytesIO()
    np.save(b, a, allow_pickle=True)
    return b.getvalue()


DIFFERS = "param 'rho' differs from the one the model was trained with"
RNG = np.random.default_rng(12)
X = 1 + RNG.random((12, 5))      # 12 samples of x
RHO = 1 + RNG.random(5)
XB = X.astype("<f8").tobytes()


def data_dir(rel, files):
    os.makedirs(path(rel), exist_ok=True)
    for name, blob in files.items():
        if blob is None:
            continue
        write(os.path.join(rel, name), blob if isinstance(blob, bytes) else npy_array(blob))


# ------------------------------------------------------------------ fixtures

def fixtures():
    for name, text in PROGRAMS.items():
        write(name, text)
    data_dir("D", {"rho.npy": RHO, "x.npy": X})
    data_dir("T", {"rho.npy": RHO, "x.npy": 1 + RNG.random((4, 5))})
    data_dir("DE", {"x.npy": X, "v.npy": X * 2})
    subprocess.run([NPGC, "train", "vec.npg", "D", "-o", "M"], cwd=W, check=True, stdout=subprocess.DEVNULL)
    subprocess.run([NPGC, "train", "ext.npg", "DE", "-o", "ME"], cwd=W, check=True, stdout=subprocess.DEVNULL)


# ------------------------------------------------------------------ 1. malformed and lying .npy files

def npy_cases():
    """Each recipe replaces one file of the data set D; the result is fed to
    eval --full, train and verify (against the model M). `{f}` in a message is
    the damaged file's path. (No FIFO: npgc reads one as any Unix reader does,
    waiting for its writer, and reading from a pipe is a feature.)"""
    x = {}   # name -> (bytes or array or a callable making the file, message)
    H = npy_header
    x["empty"] = (b"", "{f}: empty file")
    x["bad_magic"] = (npy_bytes(H(), XB, magic=b"\x93NUMPZ"), "{f}: not a .npy file (bad magic)")
    x["text_file"] = (b"x = [1, 2, 3]\n", "{f}: not a .npy file (bad magic)")
    x["magic_only"] = (b"\x93NUMPY", "{f}: truncated header: expected 8 bytes, found 6")
    x["magic_cut"] = (b"\x93NUM", "{f}: truncated header: expected 8 bytes, found 4")
    x["version_4"] = (npy_bytes(H(), XB, version=(4, 0)), "unsupported .npy format version 4.0")
    x["version_1_1"] = (npy_bytes(H(), XB, version=(1, 1)), "unsupported .npy format version 1.1")
    x["version_0"] = (npy_bytes(H(), XB, version=(0, 0)), "unsupported .npy format version 0.0")
    x["header_len_cut"] = (b"\x93NUMPY\x01\x00\x76", "{f}: truncated header: expected 10 bytes, found 9")
    x["header_len_lies"] = (npy_bytes(H(), b"", hlen=4000), "{f}: truncated header: expected 4010 bytes")
    x["header_len_huge"] = (npy_bytes(H(), XB, version=(2, 0), hlen=0xFFFFFFFF),
                            "header of 4294967295 bytes is too long")
    x["header_blank"] = (npy_bytes(" " * 40, XB), "{f}: header is not a dict: it is blank")
    x["header_list"] = (npy_bytes("[1, 2, 3]", XB), "{f}: header is not a dict")
    x["header_no_shape"] = (npy_bytes("{'descr': '<f8', 'fortran_order': False, }", XB), "header has no 'shape' key")
    x["header_no_descr"] = (npy_bytes("{'fortran_order': False, 'shape': (12, 5), }", XB), "header has no 'descr' key")
    x["header_extra_key"] = (npy_bytes(H(extra="'owner': 'me', "), XB), "header has unexpected key 'owner'")
    x["header_key_twice"] = (npy_bytes(H(extra="'shape': (12, 5), "), XB), "header has key 'shape' twice")
    x["header_key_typo"] = (npy_bytes("{'descr: '<f8', 'fortran_order': False, 'shape': (12, 5), }", XB),
                            "{f}: header has unexpected key 'descr: '")
    x["header_unterminated"] = (npy_bytes("{'descr': '<f8", XB),
                                "{f}: malformed header dict at byte 10: cannot parse the value of 'descr'")
    x["header_no_close"] = (npy_bytes("{'descr': '<f8', 'fortran_order': False, 'shape': (12, 5), ", XB),
                            "malformed header dict")
    x["header_after_dict"] = (npy_bytes(H() + " junk", XB), "unexpected text after '}'")
    x["header_nul"] = (npy_bytes(H().replace("'<f8'", "'<f\x008'"), XB), "unsupported dtype")
    x["header_deep"] = (npy_bytes(H(shape="(" * 40 + ")" * 40), XB), "cannot parse the value of 'shape'")
    x["header_unpadded"] = (npy_bytes(H(shape="(13, 5)"), XB, pad=False), "{f}: truncated: expected 520 bytes")
    x["descr_f4"] = (npy_bytes(H(descr="'<f4'"), X.astype("<f4").tobytes()), "{f}: unsupported dtype '<f4'")
    x["descr_big_endian"] = (npy_bytes(H(descr="'>f8'"), X.astype(">f8").tobytes()),
                             "{f}: big-endian dtype '>f8' is not supported")
    x["descr_bool"] = (np.ones((12, 5), dtype=bool), "{f}: unsupported dtype '|b1'")
    x["descr_object"] = (np.array([[None] * 5] * 12, dtype=object), "{f}: unsupported dtype '|O'")
    x["descr_complex"] = (X.astype(complex), "{f}: unsupported dtype '<c16'")
    x["descr_uint64"] = (X.astype("<u8"), "{f}: unsupported dtype '<u8'")
    x["descr_int64"] = (X.astype("<i8"), "{f}: input 'x' must be float64, the array is int64")
    x["descr_int32"] = (X.astype("<i4"), "{f}: input 'x' must be float64, the array is int32")
    x["descr_string"] = (np.array([["a"] * 5] * 12), "{f}: unsupported dtype '<U1'")
    x["descr_struct"] = (npy_bytes(H(descr="[('a', '<f8')]"), XB), "{f}: unsupported dtype")
    x["descr_number"] = (npy_bytes(H(descr="8"), XB), "{f}: unsupported dtype 8")
    x["fortran_true"] = (np.asfortranarray(X), "{f}: Fortran-order arrays are not supported")
    x["fortran_lies"] = (npy_bytes(H(fortran="True"), XB), "{f}: Fortran-order arrays are not supported")
    x["fortran_bad"] = (npy_bytes(H(fortran="'no'"), XB), "{f}: 'fortran_order' is not True or False: 'no'")
    x["shape_bigger"] = (npy_bytes(H(shape="(13, 5)"), XB), "{f}: truncated: expected 520 bytes of data, found 480")
    x["shape_smaller"] = (npy_bytes(H(shape="(11, 5)"), XB),
                          "{f}: trailing garbage: expected 440 bytes of data, found 480")
    x["shape_huge"] = (npy_bytes(H(shape="(1000000000000, 5)"), XB), "{f}: truncated: expected 40000000000000 bytes")
    x["shape_overflow"] = (npy_bytes(H(shape="(4611686018427387904, 4611686018427387904)"), XB),
                           "has too many elements")
    x["shape_too_large"] = (npy_bytes(H(shape="(99999999999999999999999, 5)"), XB),
                            "{f}: shape entry 99999999999999999999999 is too large")
    x["shape_negative"] = (npy_bytes(H(shape="(-12, 5)"), XB), "{f}: shape entry -12 is negative")
    x["shape_float"] = (npy_bytes(H(shape="(12.0, 5)"), XB), "{f}: shape entry 12.0 is not an integer")
    x["shape_string"] = (npy_bytes(H(shape="('12', 5)"), XB), "{f}: shape entry '12' is not an integer")
    x["shape_not_tuple"] = (npy_bytes(H(shape="[12, 5]"), XB), "{f}: 'shape' is not a tuple of integers")
    x["shape_paren_int"] = (npy_bytes(H(shape="(60)"), XB), "{f}: 'shape' is not a tuple of integers: (60)")
    x["shape_nine_dims"] = (npy_bytes(H(shape="(12, 5, 1, 1, 1, 1, 1, 1, 1)"), XB), "has 9 dimensions; at most 8")
    x["shape_long_v3"] = (npy_bytes(H(shape="(12L, 5)"), XB, version=(3, 0)), "{f}: shape entry 12L is not an integer")
    x["trailing_byte"] = (npy_array(X) + b"\0", "{f}: trailing garbage: expected 480 bytes of data, found 481")
    x["data_cut"] = (npy_array(X)[:-1], "{f}: truncated: expected 480 bytes of data, found 479")
    x["data_missing"] = (npy_array(X)[:128], "{f}: truncated: expected 480 bytes of data, found 0")
    # the shape expected and the one found, both written out (issue 28)
    axes = "{f}: input 'x' needs the shape (samples, N) (a leading sample axis, then its 1 axis), the array's shape is "
    x["one_axis"] = (X.reshape(60), axes + "(60,)")
    x["three_axes"] = (X.reshape(12, 5, 1), axes + "(12, 5, 1)")
    x["zero_d"] = (np.float64(3), axes + "()")
    x["nan"] = (np.where(np.arange(60).reshape(12, 5) == 37, np.nan, X), "{f}: input 'x' holds NaN at sample 7, [2]")
    x["inf"] = (np.where(np.arange(60).reshape(12, 5) == 59, np.inf, X),
                "{f}: input 'x' holds an infinity at sample 11, [4]")
    x["minus_inf"] = (np.where(np.arange(60).reshape(12, 5) == 0, -np.inf, X),
                      "{f}: input 'x' holds an infinity at sample 0, [0]")
    x["is_directory"] = (lambda p: os.mkdir(p), "{f}: cannot read: Is a directory")
    x["missing"] = (lambda p: None, "{f}: cannot open: No such file or directory")
    x["dangling_link"] = (lambda p: os.symlink("nowhere.npy", p), "{f}: cannot open: No such file or directory")
    x["link_to_dev_null"] = (lambda p: os.symlink("/dev/null", p), "{f}: empty file")
    x["link_loop"] = (lambda p: os.symlink(os.path.basename(p), p), "{f}: cannot open: Too many levels of symbolic links")
    x["sparse_8g"] = (lambda p: (write_path(p, npy_array(X)), os.truncate(p, 8 << 30)),
                      "{f}: trailing garbage: expected 480 bytes of data, found 8589934464")
    for name, (blob, msg) in x.items():
        npy_data_case("x_" + name, "x.npy", blob, msg)

    # the param rho
    p = {}
    p["empty"] = (b"", "{f}: empty file")
    p["bad_magic"] = (npy_bytes(npy_header(shape="(5,)"), RHO.tobytes(), magic=b"\x93NUMPz"), "{f}: not a .npy file")
    p["descr_f4"] = (RHO.astype("<f4"), "{f}: unsupported dtype '<f4'")
    p["descr_int64"] = (RHO.astype("<i8"), "{f}: param 'rho' is declared real but the array is int64")
    p["nan"] = (np.where(np.arange(5) == 3, np.nan, RHO), "{f}: param 'rho' holds NaN at [3]")
    p["inf"] = (np.where(np.arange(5) == 0, np.inf, RHO), "{f}: param 'rho' holds an infinity at [0]")
    p["matrix"] = (RHO.reshape(5, 1), "{f}: 'rho' has 1 axis, but the array has 2")
    p["scalar"] = (np.float64(1), "{f}: 'rho' has 1 axis, but the array has 0")
    p["other_size"] = (1 + RNG.random(6), {"*": "dim N is 6 in {f} but 5 in {d}/x.npy", "verify": DIFFERS})
    p["zero_size"] = (np.zeros(0), {"*": "dim N is 0 in {f} but 5 in {d}/x.npy", "verify": DIFFERS})
    p["truncated"] = (npy_array(RHO)[:-3], "{f}: truncated: expected 40 bytes of data, found 37")
    p["shape_lies"] = (npy_bytes(npy_header(shape="(6,)"), RHO.tobytes()), "{f}: truncated: expected 48 bytes")
    p["missing"] = (lambda p: None, "{f}: cannot open: No such file or directory")
    for name, (blob, msg) in p.items():
        npy_data_case("rho_" + name, "rho.npy", blob, msg)


def write_path(p, blob):
    with open(p, "wb") as f:
        f.write(blob)


def make_file(rel, blob):
    p = path(rel)
    if os.path.lexists(p):
        os.remove(p)
    if callable(blob):
        blob(p)
    else:
        write(rel, blob if isinstance(blob, bytes) else npy_array(blob))


def expect(msg, cmd, **subst):
    """The (status, message) of command `cmd` from a recipe's expectation: a
    message, a (status, message), or a dict of those by command ("*": the
    others); `subst` fills {f}, {d}, {m}."""
    if isinstance(msg, dict):
        msg = msg.get(cmd, msg.get("*"))
    status, msg = msg if isinstance(msg, tuple) else (1, msg)
    for k, v in subst.items():
        msg = msg.replace("{%s}" % k, v)
    return status, msg


def npy_data_case(name, file, blob, msg):
    d = "npy/" + name
    shutil.copytree(path("D"), path(d))
    make_file(d + "/" + file, blob)
    f = d + "/" + file
    for cmd, argv in (("eval", ["eval", "vec.npg", "--full", d, d, "-o", "out/" + name]),
                      ("train", ["train", "vec.npg", d, "-o", "models/" + name]),
                      ("verify", ["verify", "vec.npg", "M", d])):
        case("npy_%s_%s" % (name, cmd), argv, *expect(msg, cmd, f=f, d=d))


def npy_other_cases():
    # sample counts that disagree across files
    data_dir("npy/counts", {"x.npy": X, "z.npy": X[:7]})
    for cmd in (["eval", "two.npg", "--full", "npy/counts", "npy/counts", "-o", "out/counts"],
                ["train", "two.npg", "npy/counts", "-o", "models/counts"]):
        case("npy_sample_counts_" + cmd[0], cmd, 1, "npy/counts/x.npy has 12 samples but npy/counts/z.npy has 7")
    # sizes of one dim that disagree across files
    data_dir("npy/dims", {"x.npy": X, "z.npy": 1 + RNG.random((12, 4))})
    case("npy_dim_disagrees_eval", ["eval", "two.npg", "--full", "npy/dims", "npy/dims", "-o", "out/dims"], 1,
         "=error: dim N is 5 in npy/dims/x.npy but 4 in npy/dims/z.npy")
    case("npy_dim_disagrees_train", ["train", "two.npg", "npy/dims", "-o", "models/dims"], 1,
         "=error: dim N is 5 in npy/dims/x.npy but 4 in npy/dims/z.npy")
    # zero samples
    data_dir("npy/no_samples", {"rho.npy": RHO, "x.npy": np.zeros((0, 5))})
    case("npy_no_samples_train", ["train", "vec.npg", "npy/no_samples", "-o", "models/no_samples"], 1,
         "=error: npy/no_samples: no samples (the first axis of its inputs is 0)")
    case("npy_no_samples_verify", ["verify", "vec.npg", "M", "npy/no_samples"], 1,
         "=error: npy/no_samples: no samples (the first axis of its inputs is 0)")
    case("npy_no_samples_eval_reduced", ["eval", "vec.npg", "M", "npy/no_samples", "-o", "out/no_samples"], 1,
         "=error: npy/no_samples: no samples (the first axis of its inputs is 0)")
    # accepted: the full evaluation of no samples is an empty output
    case("npy_no_samples_eval_full", ["eval", "vec.npg", "--full", "npy/no_samples", "npy/no_samples", "-o",
                                      "out/no_samples_full"], 0, "")
    # accepted: a zero-size dim evaluates to empty outputs
    data_dir("npy/zero_dim", {"x.npy": np.zeros((4, 0)), "z.npy": np.zeros((4, 0))})
    case("npy_zero_size_dim_eval_full", ["eval", "two.npg", "--full", "npy/zero_dim", "npy/zero_dim", "-o",
                                         "out/zero_dim"], 0, "")
    # a test set whose inputs have another size than the model's
    data_dir("npy/wider", {"rho.npy": 1 + RNG.random(6), "x.npy": 1 + RNG.random((3, 6))})
    case("npy_wider_eval_reduced", ["eval", "vec.npg", "M", "npy/wider", "-o", "out/wider"], 1, "npy/wider/rho.npy: " + DIFFERS)
    case("npy_wider_verify", ["verify", "vec.npg", "M", "npy/wider"], 1, "npy/wider/rho.npy: " + DIFFERS)
    # int params: as floats, out of range, negative, beyond 2^53, int32
    ix = 1 + RNG.random((12, 6))
    good = np.array([[0, 1], [1, 2], [2, 3], [4, 5]])
    for name, e, msg in [
        ("as_float", good.astype(float), "{f}: param 'e' is declared int but the array is float64"),
        ("as_f4", good.astype("<f4"), "{f}: unsupported dtype '<f4'"),
        ("out_of_range", np.array([[0, 1], [1, 2], [2, 6], [4, 5]]),
         "=gather.npg:4:32: error: {f}: entry [2, 1] = 6 is out of range for dim N (size 6), used as an index in stage 'y'"),
        ("negative", np.array([[0, 1], [-7, 2], [2, 3], [4, 5]]),
         "=gather.npg:4:19: error: {f}: entry [1, 0] = -7 is out of range for dim N (size 6), used as an index in stage 'y'"),
        ("beyond_2_53", np.array([[0, 1], [2**53 + 1, 2], [2, 3], [4, 5]]),
         "{f}: int param 'e' holds 9007199254740993 at flat entry 2, beyond 2^53"),
        ("huge_int64", np.array([[0, 1], [2**62, 2], [2, 3], [4, 5]]),
         "{f}: int param 'e' holds 4611686018427387904 at flat entry 2, beyond 2^53"),
        ("one_axis", good.reshape(8), "{f}: 'e' has 2 axes, but the array has 1"),
        ("three_columns", np.array([[0, 1, 2], [1, 2, 3]]),
         "{f}: axis 1 of 'e' is static with size 2, but the array has 3"),
        ("bool", good.astype(bool), "{f}: unsupported dtype '|b1'"),
    ]:
        d = "npy/e_" + name
        data_dir(d, {"x.npy": ix, "e.npy": e})
        case("npy_e_%s_eval" % name, ["eval", "gather.npg", "--full", d, d, "-o", "out/e_" + name],
             *expect(msg, "eval", f=d + "/e.npy"))
        case("npy_e_%s_train" % name, ["train", "gather.npg", d, "-o", "models/e_" + name],
             *expect(msg, "train", f=d + "/e.npy"))
    # a value that is not finite where it arises: a root of a negative entry, 1/0
    xr = 1 + RNG.random((6, 5))
    xr[4, 2] = -1
    data_dir("npy/root", {"x.npy": xr})
    case("npy_root_of_negative_eval", ["eval", "root.npg", "--full", "npy/root", "npy/root", "-o", "out/root"], 1,
         "sample 4: stage 'y' is not finite: y[2] is NaN")
    case("npy_root_of_negative_train", ["train", "root.npg", "npy/root", "-o", "models/root"], 1,
         "training sample 4: y is not finite (y[2] is NaN)")
    xd = 1 + RNG.random((6, 5))
    xd[1, 0] = 0
    data_dir("npy/div", {"x.npy": xd})
    case("npy_division_by_zero_eval", ["eval", "div.npg", "--full", "npy/div", "npy/div", "-o", "out/div"], 1,
         "sample 1: stage 'y' is not finite: y[0]")
    case("npy_division_by_zero_train", ["train", "div.npg", "npy/div", "-o", "models/div"], 1,
         "training sample 1: y is not finite (y[0] is inf)")
    # an extern without its values, and with NaN values
    data_dir("npy/ext_missing", {"x.npy": X})
    case("npy_extern_missing_train", ["train", "ext.npg", "npy/ext_missing", "-o", "models/ext_missing"], 1,
         "npy/ext_missing/v.npy: cannot open")
    data_dir("npy/ext_nan", {"x.npy": X, "v.npy": np.where(np.arange(60).reshape(12, 5) == 6, np.nan, X)})
    case("npy_extern_nan_train", ["train", "ext.npg", "npy/ext_nan", "-o", "models/ext_nan"], 1,
         "npy/ext_nan/v.npy: extern 'v' holds NaN at sample 1, [1]")
    # reduced eval of a NaN input
    data_dir("npy/nan_in", {"rho.npy": RHO, "x.npy": np.where(np.arange(60).reshape(12, 5) == 11, np.nan, X)})
    case("npy_nan_input_eval_reduced", ["eval", "vec.npg", "M", "npy/nan_in", "-o", "out/nan_in"], 1,
         "npy/nan_in/x.npy: input 'x' holds NaN at sample 2, [1]")
    # a huge sample axis, lying: refused before anything is allocated
    data_dir("npy/huge", {"rho.npy": RHO, "x.npy": npy_bytes(npy_header(shape="(100000000000, 5)"), XB)})
    case("npy_huge_eval_reduced", ["eval", "vec.npg", "M", "npy/huge", "-o", "out/huge"], 1,
         "npy/huge/x.npy: truncated")
    case("npy_huge_bench", ["bench", "vec.npg", "M", "npy/huge"], 1, "npy/huge/x.npy: truncated")


# ------------------------------------------------------------------ 2. damaged models

def manifest_lines(d):
    with open(path(d, "manifest"), "rb") as f:
        return f.read().split(b"\n")[:-1]


def set_manifest(d, lines, seal):
    """Write `lines` as d/manifest; with `seal`, the last line is replaced by
    the checksum of the others, as a forger who knows the format would."""
    if seal:
        body = b"".join(l + b"\n" for l in lines if not l.startswith(b"manifest "))
        text = body + b"manifest fnv1a64 %016x\n" % fnv1a64(body)
    else:
        text = b"".join(l + b"\n" for l in lines)
    with open(path(d, "manifest"), "wb") as f:
        f.write(text)


def model_cases():
    """Each recipe damages a copy of the model M; the result is fed to verify,
    the reduced eval and emit --reduced. `{m}` in a message is the copy."""
    c = {}

    def edit(fn, seal=False):
        return lambda d: set_manifest(d, fn(manifest_lines(d)), seal)

    def replace(prefix, new, seal=False):
        return edit(lambda ls: [new if l.startswith(prefix) else l for l in ls], seal)

    def file_op(fn):
        return fn

    def array_name(d, k):
        return [l.split(b" ")[1].decode() for l in manifest_lines(d) if l.startswith(b"array ")][k]

    # the manifest itself, unsealed: its checksum catches the change
    c["manifest_missing"] = (lambda d: os.remove(path(d, "manifest")), "{m}/manifest: cannot open")
    c["manifest_empty"] = (lambda d: open(path(d, "manifest"), "w").close(), "{m}/manifest:1: empty file")
    c["manifest_directory"] = (lambda d: (os.remove(path(d, "manifest")), os.mkdir(path(d, "manifest"))),
                               "{m}/manifest: cannot read: Is a directory")
    c["manifest_dev_zero"] = (lambda d: (os.remove(path(d, "manifest")), os.symlink("/dev/zero", path(d, "manifest"))),
                              "{m}/manifest: larger than 16777216 bytes: not a model manifest")
    c["manifest_sparse_8g"] = (lambda d: os.truncate(path(d, "manifest"), 8 << 30),
                               "{m}/manifest: larger than 16777216 bytes: not a model manifest")
    c["manifest_binary"] = (lambda d: write(os.path.join(d, "manifest"), bytes(range(256))),
                            "{m}/manifest:1: line holds a NUL byte")
    c["manifest_format_4"] = (replace(b"npg-model 1", b"npg-model 4"), "{m}/manifest:1: model format 'npg-model 4'")
    c["manifest_first_line"] = (edit(lambda ls: ls[1:]), "{m}/manifest:1: not a model manifest")
    c["manifest_dims_removed"] = (edit(lambda ls: [l for l in ls if not l.startswith(b"dims")]),
                                  "checksum mismatch: the manifest was changed after training")
    c["manifest_line_duplicated"] = (edit(lambda ls: ls[:4] + ls[3:]), "checksum mismatch: the manifest was changed")
    c["manifest_lines_swapped"] = (edit(lambda ls: ls[:2] + [ls[3], ls[2]] + ls[4:]),
                                   "checksum mismatch: the manifest was changed")
    c["manifest_arrays_reordered"] = (edit(lambda ls: ls[:-5] + [ls[-4], ls[-5]] + ls[-3:]),
                                      "checksum mismatch: the manifest was changed")
    c["manifest_checksum_removed"] = (edit(lambda ls: ls[:-1]), "{m}/manifest: no 'manifest' checksum line")
    c["manifest_checksum_changed"] = (replace(b"manifest ", b"manifest fnv1a64 0123456789abcdef"),
                                      "checksum mismatch: the manifest was changed after training")
    c["manifest_checksum_short"] = (replace(b"manifest ", b"manifest fnv1a64 0123"),
                                    "expected 'manifest fnv1a64 <16 hex digits>'")
    c["manifest_checksum_first"] = (edit(lambda ls: [ls[-1]] + ls[:-1]), "{m}/manifest:1: not a model manifest")
    c["manifest_checksum_not_last"] = (edit(lambda ls: ls[:-1] + [ls[-1], b"dims N=5"]),
                                       "the 'manifest' checksum line must be the last")
    c["manifest_no_newline"] = (lambda d: open(path(d, "manifest"), "r+b").truncate(
        os.path.getsize(path(d, "manifest")) - 1), "last line has no newline")
    c["manifest_cut"] = (lambda d: open(path(d, "manifest"), "r+b").truncate(120),
                         "{m}/manifest:7: last line has no newline: the file was cut short?")
    c["manifest_crlf"] = (edit(lambda ls: [l + b"\r" for l in ls]),
                          "{m}/manifest:1: model format 'npg-model 1\\x0d' is not supported")
    c["manifest_nul"] = (edit(lambda ls: ls[:3] + [b"dims N=5\0junk"] + ls[4:]), "{m}/manifest:4: line holds a NUL byte")
    c["manifest_blank_line"] = (edit(lambda ls: ls[:3] + [b""] + ls[3:]), "{m}/manifest:4: empty line")
    c["manifest_leading_space"] = (edit(lambda ls: ls[:3] + [b" " + ls[3]] + ls[4:]), "line starts with a space")
    c["array_checksum_changed"] = (edit(lambda ls: [l[:-16] + b"0000000000000000" if l.startswith(b"array basis_0")
                                                    else l for l in ls]),
                                   "{m}/basis_0.npy: checksum mismatch")
    c["array_checksum_bad_hex"] = (edit(lambda ls: [l[:-16] + b"zzzzzzzzzzzzzzzz" if l.startswith(b"array basis_0")
                                                    else l for l in ls]), "bad checksum 'zzzzzzzzzzzzzzzz'")
    c["array_kind_unknown"] = (edit(lambda ls: [l.replace(b"fnv1a64", b"sha256") if l.startswith(b"array basis_0")
                                                else l for l in ls]), "unknown checksum kind 'sha256'")
    c["array_line_short"] = (edit(lambda ls: [b"array basis_0.npy 5x5" if l.startswith(b"array basis_0") else l
                                              for l in ls]), "expected 'array <name>.npy <shape> fnv1a64")
    # a class marked streamed (issue 30) whose basis the reduced model reads: refused, though sealed
    c["streamed_input_class"] = (edit(lambda ls: ls + [b"streamed 0"], seal=True),
                                 "is marked streamed, but the reduced model reads its basis")
    # the array files
    c["basis_truncated"] = (lambda d: open(path(d, "basis_0.npy"), "r+b").truncate(100),
                            "{m}/basis_0.npy: checksum mismatch: the file is corrupted or was changed after training")
    c["basis_deleted"] = (lambda d: os.remove(path(d, "basis_0.npy")), "{m}/basis_0.npy: cannot open")
    c["basis_directory"] = (lambda d: (os.remove(path(d, "basis_0.npy")), os.mkdir(path(d, "basis_0.npy"))),
                            "{m}/basis_0.npy: cannot read: Is a directory")
    c["basis_sparse_8g"] = (lambda d: os.truncate(path(d, "basis_0.npy"), 8 << 30),
                            "{m}/basis_0.npy: 8589934592 bytes, more than an array of shape 5x5 can take")
    c["bases_swapped"] = (lambda d: (os.rename(path(d, "basis_0.npy"), path(d, "t")),
                                     os.rename(path(d, "basis_1.npy"), path(d, "basis_0.npy")),
                                     os.rename(path(d, "t"), path(d, "basis_1.npy"))),
                          "{m}/basis_0.npy: checksum mismatch")
    c["basis_replaced"] = (lambda d: write(os.path.join(d, "basis_0.npy"), npy_array(np.eye(5))),
                           "{m}/basis_0.npy: checksum mismatch")
    c["basis_byte_flipped"] = (lambda d: flip_byte(path(d, "basis_0.npy"), 200), "{m}/basis_0.npy: checksum mismatch")
    c["tensor_emptied"] = (lambda d: open(path(d, array_name(d, 2)), "w").close(), "checksum mismatch")
    c["tensor_to_dev_null"] = (lambda d: (os.remove(path(d, array_name(d, 3))),
                                          os.symlink("/dev/null", path(d, array_name(d, 3)))), "checksum mismatch")
    # the program changed after training, or another program
    c["program_hash_changed"] = (replace(b"program ", b"program 0000000000000000"),
                                 "{m}/manifest: model was trained for another program (program hash 0000000000000000")
    # sealed forgeries: the manifest's checksum is right, its contents lie
    c["sealed_program_other"] = (replace(b"program ", b"program 0000000000000001", True),
                                 "{m}/manifest: model was trained for another program")
    c["sealed_program_twice"] = (edit(lambda ls: ls[:2] + ls[1:], True), "second 'program' line")
    c["sealed_no_program"] = (edit(lambda ls: [l for l in ls if not l.startswith(b"program")], True),
                              "{m}/manifest: no 'program' line")
    c["sealed_dims_removed"] = (edit(lambda ls: [l for l in ls if not l.startswith(b"dims")], True),
                                "{m}/manifest: no 'dims' line")
    c["sealed_dims_other"] = (replace(b"dims", b"dims N=6", True), "{m}/basis_0.npy: wrong shape, class {x} needs 6 rows")
    c["sealed_dims_huge"] = (replace(b"dims", b"dims N=99999999999999999999", True),
                             "{m}/manifest: dim N has no valid size")
    c["sealed_dims_negative"] = (replace(b"dims", b"dims N=-5", True), "{m}/manifest: dim N has no valid size")
    c["sealed_dims_zero"] = (replace(b"dims", b"dims N=0", True), "{m}/basis_0.npy: wrong shape, class {x} needs 0 rows")
    c["sealed_dims_garbage"] = (replace(b"dims", b"dims N=five", True), "{m}/manifest: dim N has no valid size")
    c["sealed_dims_no_value"] = (replace(b"dims", b"dims M=5", True), "{m}/manifest: no size for dim N")
    c["sealed_params_removed"] = (edit(lambda ls: [l for l in ls if not l.startswith(b"params")], True),
                                  "=error: {m}/manifest: no 'params' line: the model is damaged; retrain")
    c["sealed_samples_removed"] = (edit(lambda ls: [l for l in ls if not l.startswith(b"samples")], True),
                                   "{m}/manifest: no 'samples' line: the model is damaged")
    c["sealed_bytes_removed"] = (edit(lambda ls: [l for l in ls if not l.startswith(b"bytes")], True),
                                 "{m}/manifest: no 'bytes' line: the model is damaged")
    c["sealed_class_removed"] = (edit(lambda ls: [l for l in ls if not l.startswith(b"class 1 ")], True),
                                 "{m}/manifest: no 'class 1 {y}' line: the model is damaged")
    c["sealed_member_removed"] = (edit(lambda ls: [l for l in ls if not l.startswith(b"member 0 ")], True),
                                  "{m}/manifest: no 'member 0 x' line: the model is damaged")
    c["sealed_params_incomplete"] = (replace(b"params", b"params sigma=0000000000000000", True),
                                     "{m}/manifest: no hash of param 'rho' in its 'params' line: the model is damaged")
    c["sealed_params_other"] = (replace(b"params", b"params rho=0000000000000000", True),
                                {"*": "T/rho.npy: " + DIFFERS, "emit": (0, "")})
    c["sealed_samples_negative"] = (replace(b"samples", b"samples -5", True), "samples")
    c["sealed_array_shape"] = (edit(lambda ls: [l.replace(b" 5x5 ", b" 5x4 ", 1) if l.startswith(b"array basis_0")
                                                else l for l in ls], True),
                               "{m}/basis_0.npy: shape 5x5, manifest says 5x4")
    c["sealed_array_twice"] = (edit(lambda ls: ls[:-2] + [ls[-3]] + ls[-2:], True), "listed twice")
    c["sealed_array_path"] = (edit(lambda ls: [b"array ../D/x.npy 12x5 fnv1a64 0000000000000000"
                                               if l.startswith(b"array basis_0") else l for l in ls], True),
                              "bad array name '../D/x'")
    c["sealed_array_not_npy"] = (edit(lambda ls: [l.replace(b"basis_0.npy", b"basis_0.txt")
                                                  if l.startswith(b"array basis_0") else l for l in ls], True),
                                 "array file 'basis_0.txt' does not end in .npy")
    c["sealed_array_removed"] = (edit(lambda ls: [l for l in ls if not l.startswith(b"array basis_1")], True),
                                 "{m}/basis_1.npy: missing, class {y} needs 5 rows")
    c["sealed_array_shape_huge"] = (edit(lambda ls: [l.replace(b" 5x5 ", b" 99999999999999999999x5 ", 1)
                                                     if l.startswith(b"array basis_0") else l for l in ls], True),
                                    "bad shape '99999999999999999999x5'")
    c["sealed_spd_added"] = (edit(lambda ls: ls[:4] + [b"spd y 0 0", b"spd y 99 99", b"spd nosuch 0 0"] + ls[4:],
                                  True), "spd")
    c["sealed_member_garbage"] = (edit(lambda ls: ls[:4] + [b"member 99 x cap -1 energy nan kept 99 captured 7",
                                                            b"member -1"] + ls[4:], True), "member")
    c["sealed_class_garbage"] = (replace(b"class 0", b"class 0 {x} n 999 m 999", True), "class")
    c["sealed_nan_basis"] = (lambda d: nan_basis(d), "{m}/basis_1.npy: holds NaN at flat entry 13: a model's arrays are finite")
    c["sealed_inf_tensor"] = (lambda d: inf_tensor(d), "holds an infinity at flat entry 4: a model's arrays are finite")
    c["sealed_tensor_shape"] = (lambda d: reshape_tensor(d), "shape 6x3, the program and the model's bases need 5x15")
    c["sealed_format_twice"] = (edit(lambda ls: ls[:3] + [ls[0]] + ls[3:], True),
                                "'npg-model' may only be the first line")
    # accepted: a metadata line the model does not use is kept, whatever its length
    c["sealed_long_line"] = (edit(lambda ls: ls[:3] + [b"note " + b"x" * 1000000] + ls[3:], True), (0, ""))
    # the model directory itself
    c["model_is_file"] = (lambda d: (shutil.rmtree(path(d)), write(d, "not a model\n")), "{m}/manifest: cannot open")
    c["model_empty"] = (lambda d: [os.remove(path(d, f)) for f in os.listdir(path(d))], "{m}/manifest: cannot open")
    for name, (fn, msg) in c.items():
        model_case(name, fn, msg)

    # retraining into a folder holding a file its manifest does not list, or not a model at all
    shutil.copytree(path("M"), path("models/unlisted"))
    write("models/unlisted/mine.npy", npy_array(X))
    case("model_unlisted_file_retrain", ["train", "vec.npg", "D", "-o", "models/unlisted"], 1,
         "models/unlisted: holds 'mine.npy', which its manifest does not list: refusing to replace the model")
    os.makedirs(path("models/mydata"))
    write("models/mydata/notes.txt", "mine\n")
    case("model_foreign_folder_retrain", ["train", "vec.npg", "D", "-o", "models/mydata"], 1,
         "models/mydata: holds 'notes.txt', which a model store never writes: refusing to replace it")
    write("models/afile", "mine\n")
    case("model_file_retrain", ["train", "vec.npg", "D", "-o", "models/afile"], 1,
         "models/afile: exists and is not a directory: refusing to replace it")
    os.symlink("../M", path("models/alink"))
    case("model_symlink_retrain", ["train", "vec.npg", "D", "-o", "models/alink"], 1, "is a symbolic link")
    # the program changed after training
    for cmd in (["verify", "vec2.npg", "M", "T"], ["eval", "vec2.npg", "M", "T", "-o", "out/vec2"],
                ["bench", "vec2.npg", "M", "T"], ["emit", "vec2.npg", "--reduced", "M", "-o", "out/vec2.c"]):
        case("model_program_changed_" + cmd[0], cmd, 1, "M/manifest: model was trained for another program")
    # a model of another program
    case("model_of_other_program", ["verify", "ext.npg", "M", "DE"], 1, "M/manifest: model was trained for another")
    # an extern's learned map damaged
    d = "models/ext_damaged"
    shutil.copytree(path("ME"), path(d))
    flip_byte(path(d, "extern_v_values.npy"), 130)
    case("model_extern_map_damaged_verify", ["verify", "ext.npg", d, "DE"], 1,
         d + "/extern_v_values.npy: checksum mismatch")


def flip_byte(p, at):
    with open(p, "r+b") as f:
        f.seek(at)
        b = f.read(1)
        f.seek(at)
        f.write(bytes([b[0] ^ 0x40]))


def reseal_array(d, name, a):
    """Replace d/name with `a` and the manifest's line of it, sealed."""
    blob = npy_array(a)
    write(os.path.join(d, name), blob)
    shape = b"x".join(b"%d" % s for s in a.shape)
    lines = [b"array %s %s fnv1a64 %016x" % (name.encode(), shape, fnv1a64(blob))
             if l.startswith(b"array " + name.encode() + b" ") else l for l in manifest_lines(d)]
    set_manifest(d, lines, True)


def nan_basis(d):
    b = np.load(path(d, "basis_1.npy"))
    b[2, 3] = np.nan
    reseal_array(d, "basis_1.npy", b)


def inf_tensor(d):
    name = [l.split(b" ")[1].decode() for l in manifest_lines(d) if l.startswith(b"array t_")][0]
    t = np.load(path(d, name))
    t.flat[4] = np.inf
    reseal_array(d, name, t)


def reshape_tensor(d):
    name = [l.split(b" ")[1].decode() for l in manifest_lines(d) if l.startswith(b"array t_")][0]
    t = np.load(path(d, name))
    reseal_array(d, name, np.ones((t.shape[0] + 1, 3)))


def model_case(name, damage, msg):
    d = "models/" + name
    shutil.copytree(path("M"), path(d))
    damage(d)
    for cmd, argv in (("verify", ["verify", "vec.npg", d, "T"]), ("eval", ["eval", "vec.npg", d, "T", "-o", "out/" + name]),
                      ("emit", ["emit", "vec.npg", "--reduced", d, "-o", "out/%s.c" % name])):
        case("model_%s_%s" % (name, cmd), argv, *expect(msg, cmd, m=d))


# ------------------------------------------------------------------ 3. pathological programs

def program_cases():
    def prog(name, text, msg, status=1, args=()):
        write("prog/%s.npg" % name, text)
        case("prog_" + name, ["check", "prog/%s.npg" % name] + list(args), status, msg)

    head = "input x : real[2]\noutput y = "
    prog("deep_parens", head + "(" * 300 + "x[0]" + ")" * 300 + "\n", "expression nested too deeply")
    prog("deep_parens_10000", head + "(" * 10000 + "x[0]" + ")" * 10000 + "\n", "expression nested too deeply")
    prog("deep_unary_minus", head + "-" * 5000 + "x[0]\n", "expression nested too deeply")
    prog("deep_power_chain", head + "x[0]" + "^1" * 5000 + "\n", "expression nested too deeply")
    prog("deep_calls", "fn f(a) = a\n" + head + "f(" * 300 + "x[0]" + ")" * 300 + "\n", "nested too deeply")
    prog("deep_vector", head + "[" * 300 + "x[0]" + "]" * 300 + "\n", "nested too deeply")
    prog("deep_fn_chain", "".join("fn f%d(a) = f%d(a) * 2\n" % (i, i - 1) if i else "fn f0(a) = a\n"
                                  for i in range(400)) + head + "f399(x[0])\n",
         "prog/deep_fn_chain.npg:337:14: error: fn calls nested too deeply (more than 64)")
    # the passes recurse over expressions: a chain taller than 400 levels is refused, never a stack overflow
    prog("flat_sum_5000_unknown", head + "+".join(["x[0]"] * 5000) + " + nosuch\n", "expression too deep (more than 400 levels")
    prog("flat_sum_25000", head + "+".join(["x[0]"] * 25000) + "\n", "expression too deep (more than 400 levels")
    prog("flat_sum_5000", head + "+".join(["x[0]"] * 5000) + "\n", "expression too deep (more than 400 levels")
    prog("flat_sum_399", head + "+".join(["x[0]"] * 399) + "\n", "", status=0)  # accepted
    prog("flat_product_25000", head + "*".join(["x[0]"] * 25000) + "\n", "expression too deep (more than 400 levels")
    prog("flat_sum_25000_unknown", head + "+".join(["x[0]"] * 25000) + " + nosuch\n", "expression too deep (more than 400 levels")
    prog("long_vector_literal", head + "[" + ", ".join(["x[0]"] * 20000) + "]\n", "", status=0)  # accepted
    prog("huge_static_shape", "input x : real[1000000000000]\noutput y[i:2] = x[i]\n",
         "a static axis size must be an integer from 1 to 64, found 1000000000000")
    prog("huge_static_shape_overflow", "input x : real[99999999999999999999999]\noutput y[i:2] = x[i]\n",
         "error: integer literal '99999999999999999999999' is too large (at most 2^53)")
    prog("static_shape_zero", "input x : real[0]\noutput y = x[0]\n",
         "error: a static axis size must be an integer from 1 to 64, found 0")
    prog("many_static_axes", "input x : real[" + ", ".join(["64"] * 8) + "]\noutput y = x[" +
         ", ".join(["0"] * 8) + "]\n",
         "error: too many static axes (at most 4)")
    prog("index_out_of_static", "input x : real[2]\noutput y = x[2]\n",
         "prog/index_out_of_static.npg:2:14: error: index 2 is out of range for axis 0 of 'x' (size 2)")
    prog("index_huge", "input x : real[2]\noutput y = x[99999999999999999999]\n",
         "error: integer literal '99999999999999999999' is too large")
    prog("unknown_name", head + "x[0] * nosuch\n", "unknown name 'nosuch'")
    prog("unknown_fn", head + "nosuch(x[0])\n", "error: unknown function 'nosuch'")
    prog("unknown_dim", "input x : real[N]\noutput y[i:N] = x[i]\n", "error: unknown dim 'N' (declare it with 'dim N')")
    prog("cycle", "dim N\ninput x : real[N]\na[i:N] = b[i]\nb[i:N] = a[i]\noutput y[i:N] = a[i]\n",
         "'b' is used before its definition")
    prog("self_reference", "dim N\ninput x : real[N]\noutput y[i:N] = y[i] + x[i]\n",
         "error: 'y' is used in its own definition")
    prog("fn_recursion", "fn f(a) = f(a)\n" + head + "f(x[0])\n", "recursion in fn 'f'")
    prog("fn_mutual_recursion", "fn f(a) = g(a)\nfn g(a) = f(a)\n" + head + "f(x[0])\n", "error: recursion in fn 'f'")
    prog("exp_of_input", head + "exp(x[0])\n", "error: 'exp' is not an elementary algebraic operation")
    prog("abs_of_input", head + "abs(x[0])\n", "error: 'abs' is not an elementary algebraic operation")
    prog("power_of_input", head + "x[0]^x[1]\n", "error: an exponent cannot depend on 'x', which varies")
    prog("irrational_power", head + "x[0]^0.5\n", "error: non-integer exponent 0.5 is not a rational literal")
    prog("condition_on_input", head + "if(x[0] > 0, x[0], x[1])\n", "error: condition depends on 'x', which varies")
    prog("division_by_literal_zero", head + "x[0] / (1 - 1)\n", "division by zero")
    prog("power_zero_denominator", head + "x[0]^(1/0)\n", "2:20: error: division by zero")
    prog("exponent_huge", head + "x[0]^1000000000\n", "error: exponent 1000000000 is too large")
    prog("number_huge", head + "x[0] * 1e999\n", "error: number '1e999' is out of the range of double")
    prog("no_output", "input x : real[2]\n", "the program has no output")
    prog("empty", "", "the program has no output")
    prog("only_comment", "# nothing\n", "the program has no output")
    prog("binary_garbage", bytes(range(256)) * 4, "prog/binary_garbage.npg:1:1: error: invalid character NUL")
    prog("nul_byte", "input x : real[2]\noutput y = x[0]\0 + x[1]\n", "prog/nul_byte.npg:2:16: error: invalid character NUL")
    prog("invalid_utf8", "input x : real[2]\noutput y = x[0] \xff\xfe\n", "2:17: error: non-ASCII byte 0xc3 in source")
    # refused since issue 24: names become file names and manifest lines (a 4,000-character dim name made an unloadable model)
    prog("long_name", "input " + "x" * 100000 + " : real[2]\noutput y = " + "x" * 100000 + "[0]\n",
         "error: the name 'xxxxxxxxxxxxxxxxxxxx...' is 100000 characters long (at most 128)")
    prog("long_comment", "#" + "c" * 2000000 + "\n", "the program has no output")
    prog("unterminated_sum", "dim N\ninput x : real[N]\noutput y = sum(k = 0..",
         "error: expected an expression, found end of file")
    prog("sum_huge_bounds", "dim N\ninput x : real[N]\noutput y = sum(k = 0..1000000000000, x[0])\n",
         "error: a sum with literal bounds is unrolled; 0..1000000000000 is too long")
    prog("sum_reversed_bounds", "dim N\ninput x : real[N]\noutput y = sum(k = 5..0, x[0])\n",
         "error: empty sum: the bounds 5..0 are inclusive and decreasing")
    prog("use_unknown_module", "use nosuch\n" + head + "x[0]\n", "cannot read module 'nosuch'")
    prog("use_path", "use ../../etc/passwd\n" + head + "x[0]\n", "error: expected a module name after 'use', found '..'")
    prog("duplicate_output", head + "x[0]\noutput y = x[1]\n", "error: redefinition of 'y' (already a stage)")
    prog("many_stages", "dim N\ninput x : real[N]\n" + "".join("s%d[i:N] = x[i] * 2\n" % i for i in range(3000)) +
         "output y[i:N] = s2999[i]\n", "", status=0)
    prog("many_terms_distinct", "input x : real[64]\noutput y = " +
         " + ".join("x[%d]*x[%d]" % (i, j) for i in range(64) for j in range(i, 64, 9)) + "\n", "", status=0)
    case("prog_dev_null", ["check", "/dev/null"], 1, "/dev/null:1:1: error: the program has no output")
    write("prog/sparse.npg", "input x : real[2]\noutput y = x[0]\n")
    os.truncate(path("prog/sparse.npg"), 8 << 30)
    case("prog_sparse_8g", ["check", "prog/sparse.npg"], 1, "=error: 'prog/sparse.npg' is larger than 64 MB: not a program")
    case("prog_dev_zero", ["check", "/dev/zero"], 1, "=error: '/dev/zero' is larger than 64 MB: not a program")
    case("prog_directory", ["check", "prog"], 1, "=error: cannot read 'prog': it is a directory, not a program")
    case("prog_missing", ["check", "nosuch.npg"], 1, "=error: cannot read 'nosuch.npg': No such file or directory")
    case("prog_data_file", ["check", "D/x.npy"], 1, "D/x.npy:1:1: error: non-ASCII byte 0x93 in source")
    case("prog_std_missing", ["check", "--std=nosuch", "prog/use_geometry.npg"], 1, "cannot read module 'geometry'")
    write("prog/use_geometry.npg", "use geometry\n" + head + "x[0]\n")
    # a program error in the commands that compile
    for cmd in (["eval", "prog/unknown_name.npg", "--full", "D", "D", "-o", "out/pe"],
                ["train", "prog/unknown_name.npg", "D", "-o", "models/pe"],
                ["verify", "prog/unknown_name.npg", "M", "T"],
                ["emit", "prog/unknown_name.npg", "-o", "out/pe.c"],
                ["verify", "prog/unknown_name.npg", "--exact"]):
        case("prog_error_" + cmd[0] + ("_exact" if "--exact" in cmd else ""), cmd, 1, "unknown name 'nosuch'")
    # a program whose dim cannot be inferred from the data
    write("prog/dim_unbound.npg", "dim N, K\nparam rho : real[N]\ninput x : real[N]\noutput y[i:K] = x[0]\n")
    case("prog_dim_unbound_eval", ["eval", "prog/dim_unbound.npg", "--full", "D", "D", "-o", "out/du"], 1,
         "=error: dim K is not bound: no param or input over it was given")


# ------------------------------------------------------------------ 4. bad command lines

def cli_cases():
    def cli(name, argv, status, msg):
        case("cli_" + name, argv, status, msg)

    cli("no_arguments", [], 2, "=usage: npgc COMMAND ... (npgc COMMAND --help for its whole usage)")
    cli("unknown_command", ["frobnicate"], 2, "=npgc: unknown command 'frobnicate' (npgc --help lists them)")
    cli("empty_command", [""], 2, "npgc: unknown command ''")
    cli("check_no_program", ["check"], 2, "npgc check: missing the program (PROG.npg)")
    cli("check_two_programs", ["check", "vec.npg", "two.npg"], 2, "more than one program given")
    cli("check_unknown_option", ["check", "vec.npg", "--frob"], 2, "npgc check: unknown option '--frob'")
    cli("check_d_empty", ["check", "vec.npg", "-d"], 2, "unknown option '-d'")
    cli("emit_no_output", ["emit", "vec.npg"], 2, "npgc emit: missing -o FILE.c")
    cli("emit_o_no_value", ["emit", "vec.npg", "-o"], 2, "npgc emit: -o needs a value")
    cli("emit_reduced_no_value", ["emit", "vec.npg", "-o", "out/e.c", "--reduced"], 2, "npgc emit: --reduced needs a value")
    cli("emit_over_program", ["emit", "vec.npg", "-o", "vec.npg"], 1, "would overwrite an input of the command")
    cli("emit_into_model", ["emit", "vec.npg", "--reduced", "M", "-o", "M/manifest"], 1, "would overwrite an input")
    cli("emit_to_directory", ["emit", "vec.npg", "-o", "D"], 1, "-o D: is a directory: refusing to replace it")
    cli("emit_under_file", ["emit", "vec.npg", "-o", "vec.npg/x.c"], 1, "vec.npg exists and is not a directory")
    cli("emit_reduced_missing_model", ["emit", "vec.npg", "--reduced", "nosuch", "-o", "out/x.c"], 1,
        "nosuch/manifest: cannot open")
    cli("eval_no_output", ["eval", "vec.npg", "--full", "D", "D"], 2, "npgc eval: missing -o OUT/")
    cli("eval_o_no_value", ["eval", "vec.npg", "--full", "D", "D", "-o"], 2, "npgc eval: -o needs a value")
    cli("eval_too_many", ["eval", "vec.npg", "--full", "D", "D", "D", "-o", "out/x"], 2,
        "npgc eval: more than one input folder given ('D' and 'D')")
    cli("eval_unknown_option", ["eval", "vec.npg", "--fast", "D", "D", "-o", "out/x"], 2, "unknown option '--fast'")
    cli("eval_missing_data", ["eval", "vec.npg", "--full", "nosuch", "D", "-o", "out/x"], 1,
        "=error: nosuch (DATA/): No such file or directory")
    cli("eval_missing_in", ["eval", "vec.npg", "--full", "D", "nosuch", "-o", "out/x"], 1,
        "=error: nosuch (IN/): No such file or directory")
    cli("eval_in_is_file", ["eval", "vec.npg", "--full", "D", "vec.npg", "-o", "out/x"], 1,
        "=error: vec.npg (IN/): not a directory")
    cli("eval_data_is_file", ["eval", "vec.npg", "--full", "vec.npg", "D", "-o", "out/x"], 1,
        "=error: vec.npg (DATA/): not a directory")
    cli("eval_missing_program", ["eval", "nosuch.npg", "--full", "D", "D", "-o", "out/x"], 1,
        "cannot read 'nosuch.npg'")
    cli("eval_program_directory", ["eval", "D", "--full", "D", "D", "-o", "out/x"], 1, "cannot read 'D': it is a directory")
    cli("eval_dev_null_program", ["eval", "/dev/null", "--full", "D", "D", "-o", "out/x"], 1, "the program has no output")
    cli("eval_out_under_file", ["eval", "vec.npg", "--full", "D", "D", "-o", "vec.npg/out"], 1, "not a directory")
    cli("eval_out_in_proc", ["eval", "vec.npg", "--full", "D", "D", "-o", "/proc/npg_out"], 1,
        "=error: cannot create /proc/npg_out: No such file or directory")
    cli("eval_reduced_model_missing", ["eval", "vec.npg", "nosuch", "T", "-o", "out/x"], 1, "nosuch/manifest: cannot open")
    cli("eval_reduced_model_is_data", ["eval", "vec.npg", "D", "T", "-o", "out/x"], 1,
        "npgc eval: D is a data folder (it holds .npy files and no manifest), not a model")
    cli("train_no_output", ["train", "vec.npg", "D"], 2, "npgc train: missing -o MODEL/")
    cli("train_o_no_value", ["train", "vec.npg", "D", "-o"], 2, "npgc train: -o needs a value")
    cli("train_extra_argument", ["train", "vec.npg", "D", "T", "-o", "models/x"], 2,
        "npgc train: more than one DATA/ folder given ('D' and 'T')")
    cli("train_unknown_option", ["train", "vec.npg", "D", "-o", "models/x", "--fast"], 2, "unknown option '--fast'")
    # each bad value named with its option and what was expected (issue 28: the range, the allowed keys)
    capr, enr = "(expected 1..1000000)", "(expected (0, 1])"
    mem = "is not a size in bytes (a positive number, optionally followed by k, M, G or T)"
    for name, opt, val, why in [
            ("cap_zero", "--cap", "0", "--cap: 0 is out of range " + capr),
            ("cap_huge", "--cap", "4294967297", "--cap: 4294967297 is out of range " + capr),
            ("cap_text", "--cap", "ten", "--cap: 'ten' is not a whole number " + capr),
            ("cap_trailing", "--cap", "3x", "--cap: '3x' is not a whole number " + capr),
            ("cap_empty", "--cap", "", "--cap: '' is not a whole number " + capr),
            ("cap_negative", "--cap", "-4", "--cap: -4 is out of range " + capr),
            ("energy_zero", "--energy", "0", "--energy: 0 is out of range " + enr),
            ("energy_above_one", "--energy", "1.5", "--energy: 1.5 is out of range " + enr),
            ("energy_nan", "--energy", "nan", "--energy: 'nan' is not a number " + enr),
            ("energy_inf", "--energy", "inf", "--energy: inf is out of range " + enr),
            ("mem_unit", "--mem", "1Q", "--mem: '1Q' " + mem), ("mem_negative", "--mem", "-1", "--mem: '-1' " + mem),
            ("mem_zero", "--mem", "0", "--mem: '0' " + mem), ("mem_huge", "--mem", "1e30T", "--mem: '1e30T' " + mem),
            ("merge_unknown", "--merge", "both", "--merge is concat or joint, not 'both'"),
            ("basis_no_colon", "--basis", "x", "--basis 'x': expected NAME:cap=N,energy=E,center=on|off"),
            ("basis_bad_option", "--basis", "x:size=3",
             "--basis 'x:size=3': unknown key 'size' (the keys are cap, energy, center and product"),
            ("basis_cap_zero", "--basis", "x:cap=0", "--basis 'x:cap=0': cap: 0 is out of range " + capr),
            ("basis_energy_two", "--basis", "x:energy=2", "--basis 'x:energy=2': energy: 2 is out of range " + enr),
            ("basis_trailing", "--basis", "x:cap=3;", "--basis 'x:cap=3;': cap: '3;' is not a whole number " + capr)]:
        cli("train_" + name, ["train", "vec.npg", "D", "-o", "models/x", opt, val], 2, "npgc train: " + why)
    cli("train_basis_unknown_name", ["train", "vec.npg", "D", "-o", "models/x", "--basis", "nosuch:cap=2"], 1,
        "=error: --basis nosuch: no quantity, class or numerator of that name; classes (members): m_x (x); m_y (y), "
        "or '*' for all")
    cli("train_basis_of_param", ["train", "vec.npg", "D", "-o", "models/x", "--basis", "rho:cap=2"], 1,
        "=error: --basis rho: no quantity, class or numerator of that name; classes (members): m_x (x); m_y (y), "
        "or '*' for all")
    cli("train_basis_of_dim", ["train", "vec.npg", "D", "-o", "models/x", "--basis", "N:cap=2"], 1,
        "=error: --basis N: no quantity, class or numerator of that name; classes (members): m_x (x); m_y (y), "
        "or '*' for all")
    cli("train_cap_no_value", ["train", "vec.npg", "D", "-o", "models/x", "--cap"], 2, "npgc train: --cap needs a value")
    cli("train_out_is_data", ["train", "vec.npg", "D", "-o", "D"], 1, "-o D would overwrite an input of the command")
    cli("train_out_is_program", ["train", "vec.npg", "D", "-o", "vec.npg"], 1, "would overwrite an input of the command")
    cli("train_data_missing", ["train", "vec.npg", "nosuch", "-o", "models/x"], 1, "nosuch/rho.npy: cannot open")
    cli("train_data_is_file", ["train", "vec.npg", "vec.npg", "-o", "models/x"], 1, "vec.npg/rho.npy: cannot open")
    cli("train_dev_null_program", ["train", "/dev/null", "D", "-o", "models/x"], 1, "the program has no output")
    cli("train_out_in_proc", ["train", "vec.npg", "D", "-o", "/proc/npg_model"], 1,
        "error: /proc/npg_model: cannot create the model's temporary directory /proc/npg_model.tmp.")
    cli("verify_no_test", ["verify", "vec.npg", "M"], 2, "npgc verify: missing TEST/")
    cli("verify_with_o", ["verify", "vec.npg", "M", "T", "-o", "out/x"], 2,
        "npgc verify: -o is an option of npgc train and eval, not of npgc verify")
    cli("verify_tol_empty", ["verify", "vec.npg", "M", "T", "--tol", ""], 2, "npgc verify: --tol: '' is not a number (expected at least 0)")
    cli("verify_tol_nan", ["verify", "vec.npg", "M", "T", "--tol", "nan"], 2, "npgc verify: --tol: 'nan' is not a number (expected at least 0)")
    cli("verify_tol_negative", ["verify", "vec.npg", "M", "T", "--tol", "-1"], 2, "npgc verify: --tol: -1 is out of range (expected at least 0)")
    cli("verify_exact_size_zero", ["verify", "vec.npg", "--exact-size", "0"], 2, "npgc verify: --exact-size: 0 is out of range (expected 1..64)")
    cli("verify_exact_size_huge", ["verify", "vec.npg", "--exact-size", "99999999999999999999"], 2,
        "npgc verify: --exact-size: 99999999999999999999 is out of range (expected 1..64)")
    cli("verify_reps", ["verify", "vec.npg", "M", "T", "--reps", "3"], 2,
        "npgc verify: --reps is an option of npgc bench, not of npgc verify")
    cli("verify_model_missing", ["verify", "vec.npg", "nosuch", "T"], 1, "nosuch/manifest: cannot open")
    cli("verify_test_missing", ["verify", "vec.npg", "M", "nosuch"], 1, "=error: nosuch/x.npy: cannot open: No such file or directory")
    cli("verify_dev_null_program", ["verify", "/dev/null", "M", "T"], 1, "the program has no output")
    cli("bench_reps_zero", ["bench", "vec.npg", "M", "T", "--reps", "0"], 2, "npgc bench: --reps: 0 is out of range (expected 1..1000000)")
    cli("bench_reps_text", ["bench", "vec.npg", "M", "T", "--reps", "many"], 2, "npgc bench: --reps: 'many' is not a whole number (expected 1..1000000)")
    cli("bench_no_test", ["bench", "vec.npg", "M"], 2, "npgc bench: missing TEST/")
    cli("bench_exact", ["bench", "vec.npg", "M", "T", "--exact"], 2,
        "npgc bench: --exact is an option of npgc verify, not of npgc bench")
    cli("bench_test_missing", ["bench", "vec.npg", "M", "nosuch"], 1, "=error: nosuch/x.npy: cannot open: No such file or directory")


# ------------------------------------------------------------------ running

def run(c):
    name, argv, status, message = c
    try:
        p = subprocess.run([NPGC] + argv, cwd=W, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        return name, "hangs: no exit within %d s" % TIMEOUT, ""
    err = p.stderr.decode("utf-8", "replace")
    out = p.stdout.decode("utf-8", "replace")
    first = err.split("\n", 1)[0]
    problem = None
    if p.returncode < 0:
        problem = "killed by signal %d" % -p.returncode
    elif any(mark in err for mark in SANITIZER_MARKS):
        problem = "sanitizer report"
    elif p.returncode == 0 and status != 0:
        problem = "exit 0 on bad input"
    elif p.returncode != status:
        problem = "exit %d, expected %d" % (p.returncode, status)
    elif message.startswith("=") and first != message[1:]:
        problem = "first line of stderr is not %r" % message[1:]
    elif not message.startswith("=") and message not in err:
        problem = "stderr lacks %r" % message
    elif status != 0 and not err.strip():
        problem = "no message"
    return name, problem, first[:200] + ("" if err.strip() else " [stdout: %s]" % out[:200])


def main():
    fixtures()
    npy_cases()
    npy_other_cases()
    model_cases()
    program_cases()
    cli_cases()
    names = [c[0] for c in CASES]
    dup = {n for n in names if names.count(n) > 1}
    assert not dup, "case names used twice: %s" % sorted(dup)
    assert set(KNOWN_FAILURES) <= set(names), "known failures that are not cases"
    todo = [c for c in CASES if not ONLY or any(o in c[0] for o in ONLY)]
    with ThreadPoolExecutor(max_workers=2) as pool:
        results = list(pool.map(run, todo))
    by_name = {c[0]: c[1] for c in CASES}
    failed, still_known, fixed = [], [], []
    for name, problem, first in results:
        if VERBOSE:
            print("%-50s %s\n    %s" % (name, problem or "ok", first))
        if name in KNOWN_FAILURES:
            (still_known if problem else fixed).append((name, problem))
        elif problem:
            failed.append((name, problem, first))
    kinds = {}
    for c in todo:
        kind = c[0].split("_")[0]
        kinds[kind] = kinds.get(kind, 0) + 1
    print("hostile corpus: %d cases (%s)" % (len(todo), ", ".join("%s %d" % kv for kv in sorted(kinds.items()))))
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
        print("FAIL %s: %s\n    npgc %s\n    stderr: %s" % (name, problem, " ".join(by_name[name]), first))
    if failed:
        print("%d of %d cases failed; work folder kept: %s" % (len(failed), len(todo), W))
        return 1
    shutil.rmtree(W, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
