#!/usr/bin/python3
"""reduced_peer.py — the numpy peer of npg's reduced evaluator (bench/bench_reduce.c, part 2).

    /usr/bin/python3 bench/reduced_peer.py DIR

DIR holds a reduced model written by model_save() (one .npy per reduced tensor: rows over the
reduced output coordinates, cols over the packed input axes, backends/model/model.h), plus what
bench_reduce wrote beside it: `layout` (the stage sequence reduced.c runs: per stage its terms,
each a numerator — tensors or a named quantity — then operator powers, each a sum of tensors),
in_<q>.npy (the given coordinates of the inputs and externs) and out_<q>.npy (npg's result for
every stage).

The peer runs the same stage sequence on the same tensors in numpy's strongest form: every
reshape and index array is prepared once, and a contraction is reshape + `@` (dgemv), the last
input axis first, as reduced.c does. Two variants, both timed (best of repeats):

  packed  the tensors exactly as stored: an input repeated k times is one packed symmetric axis
          (its packed power z = outer(x, x)[triu] is formed per call), a diagonal operator's rows
          are its packed upper triangle (scattered into a symmetric matrix per call);
  full    every symmetric axis unpacked to k full axes (off-diagonal entries split evenly over
          their arrangements), operator rows unpacked to m x m: plain dense tensors, the way one
          writes it without packing; about twice the bytes.

Inverse powers use np.linalg.solve (LAPACK gesv), fractional powers np.linalg.eigh (syevd).

Prints one line: RESULT packed <seconds> <rel diff> <bytes> full <seconds> <rel diff> <bytes>,
rel diff being max over stages of max|peer − npg| / max|npg|.
"""
import itertools
import math
import os
import sys
import time

import numpy as np


def sorted_multi_indices(m, k):
    """Sorted multi-indices (a_1 <= ... <= a_k < m) in lexicographic order, as k index arrays."""
    if k == 2:
        return list(np.triu_indices(m))
    idx = np.array(list(itertools.combinations_with_replacement(range(m), k)), dtype=np.intp)
    return [idx[:, l] for l in range(k)]


class Tensor:
    def __init__(self, data, inputs, full):
        self.inputs = inputs  # [(quantity, multiplicity, packed length)]
        self.rows = data.shape[0]
        self.full = full
        if not full:
            self.data = np.ascontiguousarray(data)
            self.steps = [int(n) for _, _, n in inputs]
        else:
            # unpack every symmetric axis: axes (rows, m, ..., m) per input
            t = data.reshape((self.rows,) + tuple(int(n) for _, _, n in inputs))
            for j in reversed(range(len(inputs))):
                q, k, n = inputs[j]
                if k == 1:
                    continue
                m = QSIZE[q]
                idx = sorted_multi_indices(m, k)
                # arrangements of each sorted multi-index: k! / prod(multiplicities!)
                counts = np.array([math.factorial(k) / np.prod([math.factorial(c) for c in
                                   np.unique(a, return_counts=True)[1]]) for a in zip(*idx)])
                lead = t.shape[: 1 + j]
                tail = t.shape[2 + j:]
                u = np.zeros(lead + (m,) * k + tail)
                packed = np.moveaxis(t, 1 + j, -1) / counts  # (..., n)
                for perm in set(itertools.permutations(range(k))):
                    sl = tuple(idx[p] for p in perm)
                    view = np.moveaxis(u, list(range(1 + j, 1 + j + k)), list(range(u.ndim - k, u.ndim)))
                    view[(Ellipsis,) + sl] = packed
                t = u
            self.data = np.ascontiguousarray(t.reshape(self.rows, -1))
            self.steps = []
            for q, k, n in inputs:
                self.steps += [QSIZE[q]] * (1 if k == 1 else k)

    def contract(self, x, out):
        """out += T ⊗ z_1 ⊗ … ⊗ z_n, the last axis first (reduced.c contract())."""
        if not self.inputs:
            out += self.data[:, 0]
            return
        zs = []
        for q, k, _ in self.inputs:
            if k == 1 or self.full:
                zs += [x[q]] * (1 if k == 1 else k)
            else:
                zs.append(sym_power(x[q], k))
        y = self.data
        for z, n in zip(reversed(zs), reversed(self.steps)):
            y = y.reshape(-1, n) @ z
        out += y


SYMIDX = {}


def sym_power(x, k):
    key = (x.shape[0], k)
    if key not in SYMIDX:
        SYMIDX[key] = sorted_multi_indices(x.shape[0], k)
    idx = SYMIDX[key]
    if k == 2:
        return np.outer(x, x)[idx[0], idx[1]]
    z = x[idx[0]].copy()
    for a in idx[1:]:
        z *= x[a]
    return z


class Op:
    def __init__(self, kind, p, q, spd, m, full):
        self.kind, self.p, self.q, self.spd, self.m, self.full = kind, p, q, spd, m, full
        self.tensors = []
        self.iu = np.triu_indices(m)

    def assemble(self, x):
        m = self.m
        acc = np.zeros(self.tensors[0].rows)
        for t in self.tensors:
            t.contract(x, acc)
        if self.kind == "diag" and not self.full:
            M = np.empty((m, m))
            M[self.iu] = acc
            M[self.iu[1], self.iu[0]] = acc
            return M
        return acc.reshape(m, m)

    def apply(self, x, v):
        M = self.assemble(x)
        if self.q == 1 and self.p > 0:
            for _ in range(self.p):
                v = M @ v
            return v
        if self.q == 1:
            for _ in range(-self.p):
                v = np.linalg.solve(M, v)
            return v
        w, V = np.linalg.eigh(M)
        return V @ (np.where(w > 0, np.abs(w) ** (self.p / self.q), 0.0) * (V.T @ v))


def load(dirname, full):
    stages, nbytes = [], 0
    with open(os.path.join(dirname, "layout")) as f:
        lines = [l.split() for l in f if l.strip()]
    for w in lines:
        if w[0] == "quantity":
            QSIZE[w[1]] = int(w[2])
            if w[3] == "given":
                GIVEN[w[1]] = np.load(os.path.join(dirname, "in_%s.npy" % w[1]))[0]
            else:
                EXPECT[w[1]] = np.load(os.path.join(dirname, "out_%s.npy" % w[1]))[0]
        elif w[0] == "stage":
            stages.append((w[1], []))
        elif w[0] == "term":
            proj = None if w[2] == "-" else np.load(os.path.join(dirname, w[2] + ".npy"))
            if proj is not None:
                nbytes += proj.nbytes
            stages[-1][1].append({"named": None if w[1] == "-" else w[1], "proj": proj, "num": [], "ops": []})
        elif w[0] == "op":
            term = stages[-1][1][-1]
            term["ops"].append(Op(w[1], int(w[2]), int(w[3]), w[4] == "1", QSIZE[stages[-1][0]], full))
        elif w[0] == "tensor":
            data = np.load(os.path.join(dirname, w[1] + ".npy"))
            assert data.shape == (int(w[2]), int(w[3])), w[1]
            inputs = [(s.split(":")[0], int(s.split(":")[1]), int(s.split(":")[2])) for s in w[4:]]
            term = stages[-1][1][-1]
            if term["ops"]:
                op = term["ops"][-1]
                if full and op.kind == "diag":  # unpack the operator rows too
                    m = op.m
                    iu = np.triu_indices(m)
                    u = np.empty((m, m, data.shape[1]))
                    u[iu] = data
                    u[iu[1], iu[0]] = data
                    data = u.reshape(m * m, -1)
                t = Tensor(data, inputs, full)
                op.tensors.append(t)
            else:
                t = Tensor(data, inputs, full)
                term["num"].append(t)
            nbytes += t.data.nbytes
    return stages, nbytes


def evaluate(stages, x):
    for name, terms in stages:
        y = np.zeros(QSIZE[name])
        for term in terms:
            if term["named"] is not None:
                v = x[term["named"]]
                v = term["proj"] @ v if term["proj"] is not None else v.copy()
            else:
                v = np.zeros(QSIZE[name])
                for t in term["num"]:
                    t.contract(x, v)
            for op in term["ops"]:
                v = op.apply(x, v)
            y += v
        x[name] = y
    return x


def best_time(stages, seconds):
    best, spent, reps = 1e30, 0.0, 0
    while reps < 20 or spent < seconds:
        x = dict(GIVEN)
        t0 = time.perf_counter()
        evaluate(stages, x)
        t = time.perf_counter() - t0
        best, spent, reps = min(best, t), spent + t, reps + 1
    return best


def stage_times(stages, seconds):
    """Best seconds of every stage alone, on the coordinates of a whole evaluation."""
    x = evaluate(stages, dict(GIVEN))
    out = []
    for st in stages:
        best, spent, reps = 1e30, 0.0, 0
        while reps < 20 or spent < seconds:
            t0 = time.perf_counter()
            evaluate([st], x)
            t = time.perf_counter() - t0
            best, spent, reps = min(best, t), spent + t, reps + 1
        out.append("%s %.1f" % (st[0], 1e6 * best))
    return " ".join(out)


def rel_diff(x):
    worst = 0.0
    for q, want in EXPECT.items():
        worst = max(worst, np.max(np.abs(x[q] - want)) / max(np.max(np.abs(want)), 1e-300))
    return worst


QSIZE, GIVEN, EXPECT = {}, {}, {}


def main():
    if len(sys.argv) != 2:
        sys.exit("usage: reduced_peer.py DIR")
    d = sys.argv[1]
    seconds = 1.0
    with open(os.path.join(d, "layout")) as f:
        for l in f:
            if l.startswith("seconds"):
                seconds = float(l.split()[1])
    out = []
    for full in (False, True):
        stages, nbytes = load(d, full)
        diff = rel_diff(evaluate(stages, dict(GIVEN)))
        out += ["full" if full else "packed", "%.6e" % best_time(stages, seconds), "%.3e" % diff, "%d" % nbytes]
        print(("STAGESFULL " if full else "STAGES ") + stage_times(stages, 0.1))
    print("RESULT " + " ".join(out))


if __name__ == "__main__":
    main()
