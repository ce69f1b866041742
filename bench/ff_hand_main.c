/* ff_hand_main.c — time the hand-written form-factor evaluator on the benchmark room.
 *
 *   ff_hand_main F [reps [t]]     F even >= 12 faces, reps timed runs (default 5), t in [0,1]
 *                                 the room deformation (default 0.5)
 *
 * Builds the room (examples/common/meshgen.c) with v = 1 everywhere (the room is convex), runs ff_hand
 * once to warm up (and fault in the output pages), then reps times, and prints the best wall
 * time (CLOCK_MONOTONIC). Every stage is then checked against a naive reference written
 * straight from the formulas (separate loops per stage, h[j,i] read from the stored h, p as a
 * division by sqrt(a)): every entry must agree to 1e-12 relative. Then geometry checks and the
 * radiosity solve. Exit status 0 when all checks pass, 1 otherwise, 2 on usage/setup errors.
 *
 * The first output line is machine-readable:
 *   ff_hand F=<F> V=<V> reps=<reps> seconds=<best> checksum=<sum of all p entries>
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "ff_hand.h"
#include "meshgen.h"

#define PI 3.14159265358979323846264338327950288

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static double *alloc_d(size_t count) {
    double *x = malloc(count * sizeof *x);
    if (!x) {
        fprintf(stderr, "ff_hand_main: out of memory (%zu doubles)\n", count);
        exit(2);
    }
    return x;
}

/* ---- naive reference: one loop per stage, literally the formulas of DESIGN §3 (docs/design.md) ---- */

static void centroid(const double *g, const int *tri, long f, double out[3]) {
    for (int k = 0; k < 3; k++)
        out[k] = (g[3 * tri[3 * f] + k] + g[3 * tri[3 * f + 1] + k] + g[3 * tri[3 * f + 2] + k]) / 3.0;
}

static double dot3(const double *x, const double *y) { return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]; }

static void ff_naive(long F, const double *g, const int *tri, const double *v, double *n, double *s,
                     double *r, double *h, double *c, double *d, double *a, double *p) {
    for (long f = 0; f < F; f++) {
        const double *g0 = &g[3 * tri[3 * f]], *g1 = &g[3 * tri[3 * f + 1]], *g2 = &g[3 * tri[3 * f + 2]];
        double e1[3], e2[3];
        for (int k = 0; k < 3; k++) e1[k] = g1[k] - g0[k], e2[k] = g2[k] - g0[k];
        n[3 * f + 0] = 0.5 * (e1[1] * e2[2] - e1[2] * e2[1]);
        n[3 * f + 1] = 0.5 * (e1[2] * e2[0] - e1[0] * e2[2]);
        n[3 * f + 2] = 0.5 * (e1[0] * e2[1] - e1[1] * e2[0]);
    }
    for (long i = 0; i < F; i++)
        for (long j = 0; j < F; j++) {
            double ci[3], cj[3], dd[3];
            centroid(g, tri, i, ci);
            centroid(g, tri, j, cj);
            for (int k = 0; k < 3; k++) dd[k] = cj[k] - ci[k];
            s[i * F + j] = dot3(&n[3 * i], dd);
        }
    for (long i = 0; i < F; i++)
        for (long j = 0; j < F; j++) {
            double ci[3], cj[3], dd[3];
            centroid(g, tri, i, ci);
            centroid(g, tri, j, cj);
            for (int k = 0; k < 3; k++) dd[k] = ci[k] - cj[k];
            r[i * F + j] = i == j ? 1.0 : dot3(dd, dd);
        }
    for (long k = 0; k < F * F; k++) h[k] = s[k] / r[k];
    for (long i = 0; i < F; i++)
        for (long j = 0; j < F; j++) c[i * F + j] = h[i * F + j] * h[j * F + i] / PI;
    for (long k = 0; k < F * F; k++) d[k] = c[k] * v[k];
    for (long f = 0; f < F; f++) a[f] = dot3(&n[3 * f], &n[3 * f]);
    for (long i = 0; i < F; i++)
        for (long j = 0; j < F; j++) p[i * F + j] = d[i * F + j] / sqrt(a[i]);
}

/* Largest elementwise relative difference |x - y| / |y| (0/0 counts as 0, x != 0 = y as inf). */
static double max_rel(const double *x, const double *y, size_t count) {
    double worst = 0.0;
    for (size_t k = 0; k < count; k++) {
        double diff = fabs(x[k] - y[k]);
        if (diff == 0.0) continue;
        double rel = y[k] != 0.0 ? diff / fabs(y[k]) : INFINITY;
        if (!(rel <= worst)) worst = rel; /* also catches NaN */
    }
    return worst;
}

/* Closed, consistently oriented triangle mesh: every directed edge (u, w) occurs once and its
 * reverse (w, u) once. Returns the number of directed edges that break this. */
typedef struct Edge { int u, w; } Edge;
static int cmp_edge(const void *x, const void *y) {
    const Edge *a = x, *b = y;
    if (a->u != b->u) return (a->u > b->u) - (a->u < b->u);
    return (a->w > b->w) - (a->w < b->w);
}
static int edge_find(const Edge *e, size_t count, int u, int w) {
    Edge key = {u, w};
    const Edge *hit = bsearch(&key, e, count, sizeof *e, cmp_edge);
    return hit != NULL;
}
static long open_edges(const Mesh *m) {
    size_t count = 3 * (size_t)m->F;
    Edge *e = malloc(count * sizeof *e);
    if (!e) return -1;
    for (long f = 0; f < m->F; f++)
        for (int k = 0; k < 3; k++) e[3 * f + k] = (Edge){m->tri[3 * f + k], m->tri[3 * f + (k + 1) % 3]};
    qsort(e, count, sizeof *e, cmp_edge);
    long bad = 0;
    for (size_t k = 0; k < count; k++) {
        if (k + 1 < count && cmp_edge(&e[k], &e[k + 1]) == 0) bad++;  /* duplicated directed edge */
        if (!edge_find(e, count, e[k].w, e[k].u)) bad++;              /* no opposite half-edge */
    }
    free(e);
    return bad;
}

static int cmp_double(const void *x, const void *y) {
    double a = *(const double *)x, b = *(const double *)y;
    return (a > b) - (a < b);
}

int main(int argc, char **argv) {
    if (argc < 2 || argc > 4) {
        fprintf(stderr, "usage: %s F [reps [t]]   (F even >= 12, reps >= 1, t in [0,1])\n", argv[0]);
        return 2;
    }
    char *end;
    errno = 0;
    long F = strtol(argv[1], &end, 10);
    if (errno || *end || end == argv[1]) {
        fprintf(stderr, "ff_hand_main: F '%s' is not an integer\n", argv[1]);
        return 2;
    }
    long reps = 5;
    if (argc > 2) {
        errno = 0;
        reps = strtol(argv[2], &end, 10);
        if (errno || *end || end == argv[2] || reps < 1) {
            fprintf(stderr, "ff_hand_main: reps '%s' is not a positive integer\n", argv[2]);
            return 2;
        }
    }
    double t = 0.5;
    if (argc > 3) {
        errno = 0;
        t = strtod(argv[3], &end);
        if (errno || *end || end == argv[3] || !isfinite(t)) {
            fprintf(stderr, "ff_hand_main: t '%s' is not a finite number\n", argv[3]);
            return 2;
        }
    }

    Mesh m;
    char err[256];
    if (mesh_room(F, t, &m, err, sizeof err) != 0) {
        fprintf(stderr, "ff_hand_main: %s\n", err);
        return 2;
    }
    const size_t FF = (size_t)F * (size_t)F;
    double *v = alloc_d(FF);
    for (size_t k = 0; k < FF; k++) v[k] = 1.0;
    double *n = alloc_d(3 * (size_t)F), *a = alloc_d((size_t)F);
    double *s = alloc_d(FF), *r = alloc_d(FF), *h = alloc_d(FF), *c = alloc_d(FF), *d = alloc_d(FF),
           *p = alloc_d(FF);

    ff_hand(F, m.V, m.g, m.tri, v, n, s, r, h, c, d, a, p); /* warm-up, faults pages in */
    double best = INFINITY;
    for (long k = 0; k < reps; k++) {
        double t0 = now();
        ff_hand(F, m.V, m.g, m.tri, v, n, s, r, h, c, d, a, p);
        double dt = now() - t0;
        if (dt < best) best = dt;
    }
    double checksum = 0.0;
    for (size_t k = 0; k < FF; k++) checksum += p[k];
    printf("ff_hand F=%ld V=%ld reps=%ld seconds=%.6g checksum=%.17g\n", F, m.V, reps, best, checksum);
    printf("  %.1f ns per (i,j) pair, %.0f MB of [F,F] output per call\n", 1e9 * best / (double)FF,
           7.0 * 8.0 * (double)FF / 1e6);

    int ok = 1;

    /* ---- correctness against the naive reference ---- */
    {
        double *n0 = alloc_d(3 * (size_t)F), *a0 = alloc_d((size_t)F);
        double *s0 = alloc_d(FF), *r0 = alloc_d(FF), *h0 = alloc_d(FF), *c0 = alloc_d(FF),
               *d0 = alloc_d(FF), *p0 = alloc_d(FF);
        ff_naive(F, m.g, m.tri, v, n0, s0, r0, h0, c0, d0, a0, p0);
        const struct { const char *name; const double *x, *y; size_t count; } st[] = {
            {"n", n, n0, 3 * (size_t)F}, {"s", s, s0, FF}, {"r", r, r0, FF}, {"h", h, h0, FF},
            {"c", c, c0, FF},           {"d", d, d0, FF}, {"a", a, a0, (size_t)F}, {"p", p, p0, FF},
        };
        printf("  reference check (max elementwise relative difference, tolerance 1e-12):");
        for (size_t k = 0; k < sizeof st / sizeof st[0]; k++) {
            double e = max_rel(st[k].x, st[k].y, st[k].count);
            printf(" %s %.1e", st[k].name, e);
            if (!(e <= 1e-12)) ok = 0;
        }
        printf(" -> %s\n", ok ? "ok" : "FAILED");
        free(n0), free(a0), free(s0), free(r0), free(h0), free(c0), free(d0), free(p0);
    }

    /* ---- geometry checks ---- */
    {
        double amin = INFINITY, amax = 0.0, rmin = INFINITY, smax_diag = 0.0, pmin = INFINITY;
        long bad_diag = 0, neg_p = 0;
        double recip = 0.0, asym_c = 0.0;
        double *rows = alloc_d((size_t)F);
        for (long i = 0; i < F; i++) {
            amin = fmin(amin, a[i]);
            amax = fmax(amax, a[i]);
        }
        for (long i = 0; i < F; i++) {
            double sum = 0.0;
            if (s[i * F + i] != 0.0) bad_diag++, smax_diag = fmax(smax_diag, fabs(s[i * F + i]));
            for (long j = 0; j < F; j++) {
                double pij = p[i * F + j];
                sum += pij;
                if (pij < pmin) pmin = pij;
                if (pij < 0.0) neg_p++;
                if (j != i && r[i * F + j] < rmin) rmin = r[i * F + j];
                if (c[i * F + j] != c[j * F + i]) asym_c = 1.0;
                /* reciprocity A_i F_ij = A_j F_ji */
                double lhs = sqrt(a[i]) * pij, rhs = sqrt(a[j]) * p[j * F + i];
                double den = fmax(fabs(lhs), fabs(rhs));
                if (den > 0.0) recip = fmax(recip, fabs(lhs - rhs) / den);
            }
            rows[i] = sum;
        }
        qsort(rows, (size_t)F, sizeof *rows, cmp_double);
        double mean = 0.0;
        for (long i = 0; i < F; i++) mean += rows[i];
        mean /= (double)F;
        /* signed volume by the divergence theorem: sum_f n_f . c_f / 3 = -volume for inward normals */
        double vol = 0.0;
        for (long f = 0; f < F; f++) {
            double cf[3];
            centroid(m.g, m.tri, f, cf);
            vol += dot3(&n[3 * f], cf) / 3.0;
        }
        long open = open_edges(&m);
        printf("  mesh: %ld faces, %ld vertices, %ld open or inconsistently wound edges, "
               "enclosed volume %.6f (normals inward: %s)\n",
               F, m.V, open, -vol, vol < 0.0 ? "yes" : "NO");
        int gok = amin > 0.0 && rmin > 0.0 && bad_diag == 0 && asym_c == 0.0 && open == 0 && vol < 0.0;
        printf("  geometry: a (squared area) in [%.3e, %.3e]; min r off-diagonal %.3e; "
               "s[i,i] != 0 on %ld faces; c symmetric: %s -> %s\n",
               amin, amax, rmin, bad_diag, asym_c == 0.0 ? "yes" : "NO", gok ? "ok" : "FAILED");
        printf("  form factors: min p %.3e (%ld entries < 0, coplanar round-off), reciprocity "
               "|A_i F_ij - A_j F_ji| / max <= %.1e\n",
               pmin, neg_p, recip);
        printf("  row sums sum_j F_ij (exact value for a closed room: 1): min %.4f, 10%% %.4f, "
               "median %.4f, mean %.4f, 90%% %.4f, max %.4f\n",
               rows[0], rows[(size_t)(0.1 * (double)(F - 1))], rows[(F - 1) / 2], mean,
               rows[(size_t)(0.9 * (double)(F - 1))], rows[F - 1]);
        if (!gok) ok = 0;
        free(rows);
    }

    /* ---- radiosity solve ---- */
    {
        double *rho = alloc_d((size_t)F), *e = alloc_d((size_t)F), *b = alloc_d((size_t)F);
        mesh_rho(&m, rho);
        long nem = mesh_emission(&m, e);
        double t0 = now();
        int info = ff_radiosity_solve(F, rho, p, e, b);
        double dt = now() - t0;
        if (info != 0) {
            printf("  radiosity: dgesv failed (info %d)\n", info);
            ok = 0;
        } else {
            double res = 0.0, bmin = INFINITY, bmax = -INFINITY, bnorm = 0.0;
            for (long i = 0; i < F; i++) {
                double y = b[i];
                for (long j = 0; j < F; j++) y -= rho[i] * p[i * F + j] * b[j];
                res = fmax(res, fabs(y - e[i]));
                bmin = fmin(bmin, b[i]);
                bmax = fmax(bmax, b[i]);
                bnorm = fmax(bnorm, fabs(b[i]));
            }
            printf("  radiosity: %ld emitting faces, dgesv %.4f s, b in [%.4f, %.4f], "
                   "residual max|(I - rho F) b - e| / max|b| = %.1e\n",
                   nem, dt, bmin, bmax, res / bnorm);
        }
        free(rho), free(e), free(b);
    }

    free(v), free(n), free(a), free(s), free(r), free(h), free(c), free(d), free(p);
    mesh_free(&m);
    return ok ? 0 : 1;
}
