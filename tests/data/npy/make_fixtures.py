#!/usr/bin/python3
"""Oracle fixtures for tests/test_npy.c: .npy files written by numpy itself.

tests/test_npy.c checks that npy_read reads these back to the values listed
here, that npy_write reproduces the version 1.0 ones byte for byte (so numpy
can load what npgc writes), and that the unsupported ones are refused with
the right message. Regenerate (Debian's python3-numpy) with

    /usr/bin/python3 tests/data/npy/make_fixtures.py

and keep the values here and in test_npy.c in step. numpy's own writer is
the independent oracle: nothing in this directory is written by npg.
"""
import os

import numpy as np
from numpy.lib import format as npformat

HERE = os.path.dirname(os.path.abspath(__file__))


def save(name, array, version=None):
    path = os.path.join(HERE, name)
    if version is None:
        np.save(path, array)  # what users do: version 1.0
    else:
        with open(path, "wb") as f:
            npformat.write_array(f, array, version=version)


# Readable: the three supported types, 0-d, 1-d, 3-d, empty; NaN and the
# signed zero pass through untouched.
save("f64_3x4.npy", np.array([[-1.5, 0.0, -0.0, 2.25],
                              [1e-300, 1e300, np.inf, -np.inf],
                              [np.nan, 3.0, 0.1, -7.0]], dtype="<f8"))
save("i32_5.npy", np.array([-2147483648, -1, 0, 7, 2147483647], dtype="<i4"))
save("i64_2x1x3.npy", np.array([[[-9223372036854775808, -1, 0]],
                                [[1, 1 << 40, 9223372036854775807]]], dtype="<i8"))
save("f64_0d.npy", np.array(2.5, dtype="<f8"))
save("f64_0x3.npy", np.zeros((0, 3), dtype="<f8"))
# Format versions 2.0 and 3.0 (4-byte header length).
save("f64_v2.npy", np.array([1.0, -2.0, 0.5], dtype="<f8"), version=(2, 0))
save("i64_v3.npy", np.array([[5, -6]], dtype="<i8"), version=(3, 0))

# The padding rule at its two ends, from numpy's own header writer: one
# space of padding, and a whole extra 64 bytes when the header would end
# exactly on the boundary. Only empty arrays with huge axes have headers
# this long, and np.save refuses those axes, so the header is written alone.
for name, shape in [("f64_pad1_header.npy", (0, 10**17, 10**17)),
                    ("f64_pad64_header.npy", (0,) + (10**12,) * 7)]:
    with open(os.path.join(HERE, name), "wb") as f:
        npformat.write_array_header_1_0(
            f, {"descr": "<f8", "fortran_order": False, "shape": shape})

# Refused, each with its own message.
save("f64_fortran_2x3.npy", np.asfortranarray(np.arange(6, dtype="<f8").reshape(2, 3)))
save("f64_big_endian.npy", np.arange(3, dtype=">f8"))
save("f32.npy", np.arange(3, dtype="<f4"))
save("c16.npy", np.arange(2, dtype="<c16"))
save("object.npy", np.array([1, "a", None], dtype=object))
